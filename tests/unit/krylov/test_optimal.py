"""minimal_residual_counts: the exact minimum of ||r_n|| over x_0 + K_n(M A, M r_0)."""
import numpy as np
import pytest
import scipy.sparse as sp

from ddsolve.krylov import pcr
from ddsolve.krylov.optimal import minimal_residual_counts


def _poly_min_residual(lam, r0, n):
    """min over p of degree n with p(0) = 1 of ||p(diag(lam)) r0||_2 (independent least squares)."""
    V = np.column_stack([lam ** j * r0 for j in range(1, n + 1)])
    c, *_ = np.linalg.lstsq(V, -r0, rcond=None)
    return float(np.linalg.norm(r0 + V @ c))


def test_diagonal_spd_matches_polynomial_minimum():
    rng = np.random.default_rng(0)
    lam = np.linspace(1.0, 4.0, 30)
    b = rng.standard_normal(30)
    res = minimal_residual_counts(np.diag(lam), b, rtol=1e-12, maxiter=5)
    assert res.residuals.size == 6
    for n in range(1, 6):
        assert res.residuals[n] == pytest.approx(_poly_min_residual(lam, b, n), rel=1e-8)
    # strictly decreasing for a spectrum of 30 distinct eigenvalues
    assert np.all(np.diff(res.residuals) < 0)


def test_k_distinct_eigenvalues_need_exactly_k_iterations():
    rng = np.random.default_rng(1)
    lam = np.repeat([1.0, 3.0, 7.0, 20.0], 10)          # 4 distinct eigenvalues
    b = rng.standard_normal(lam.size)
    res = minimal_residual_counts(sp.diags(lam), b, rtol=1e-10, maxiter=20)
    assert res.iterations == 4
    assert res.relative[3] > 1e-3                        # not earlier


def test_indefinite_two_distinct_and_preconditioned_identity():
    rng = np.random.default_rng(2)
    lam = np.array([-2.0] * 5 + [5.0] * 7)
    b = rng.standard_normal(lam.size)
    assert minimal_residual_counts(np.diag(lam), b, rtol=1e-10).iterations == 2
    # M = A^{-1}: one iteration
    A = np.diag(lam)
    assert minimal_residual_counts(A, b, M=np.diag(1 / lam), rtol=1e-10).iterations == 1


def test_matches_pcr_in_the_M_norm_on_spd():
    """PCR minimises ||r||_M over the same space (Lemma 1.3.2): equal residuals, equal counts."""
    rng = np.random.default_rng(3)
    n = 60
    lam = np.linspace(1.0, 50.0, n)                      # cond ~ 100: PCR's short recurrence stays exact enough
    A = np.diag(lam)
    M = np.diag(1.0 / rng.uniform(0.5, 2.0, n))          # SPD diagonal preconditioner
    b = rng.standard_normal(n)
    res = minimal_residual_counts(A, b, M=M, rtol=1e-6, maxiter=100, norm="M")
    kr = pcr(A, b, M=M, rtol=1e-6, maxiter=100, norm="M")
    assert res.iterations == kr.iterations
    # equal in exact arithmetic; PCR's rounding grows as the residual falls (relative 1e-6 down to ~1e-5 of r0)
    np.testing.assert_allclose(res.residuals[:20], kr.residuals[:20], rtol=1e-6)
    # the l2 minimum is never above PCR's l2 residual at the same n
    l2 = minimal_residual_counts(A, b, M=M, rtol=1e-6, maxiter=100, norm="l2")
    kr2 = pcr(A, b, M=M, rtol=1e-6, maxiter=100)
    m = min(kr2.residuals.size, l2.residuals.size)
    assert np.all(l2.residuals[:m] <= kr2.residuals[:m] * (1 + 1e-8))
    assert l2.iterations <= kr2.iterations


def test_x0_callable_and_errors():
    rng = np.random.default_rng(4)
    lam = np.array([1.0, 2.0, 3.0])
    b = rng.standard_normal(3)
    x0 = np.linalg.solve(np.diag(lam), b)
    assert minimal_residual_counts(lambda v: lam * v, b, x0=x0).iterations == 0
    res = minimal_residual_counts(lambda v: lam * v, b, rtol=1e-12, maxiter=10)
    assert res.iterations == 3
    with pytest.raises(ValueError):
        minimal_residual_counts(np.eye(3), b, norm="H")
    with pytest.raises(ValueError):
        minimal_residual_counts(np.eye(3), b, rtol=0.0)
