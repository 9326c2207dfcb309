"""Krylov-layer defects a black-box review (2026-11-28) reproduced on users' own operators."""
from __future__ import annotations

import numpy as np
import pytest

from ddsolve.errors import InputError
from ddsolve.krylov import PCG, pcg, pcr


def test_x0_with_a_projection_is_judged_by_the_projected_residual():
    """With P, b large outside range(P) and tiny inside it, x0 = 0 (100% wrong) was accepted as 'x0 solves the
    system to rounding' after 0 iterations: the rounding floor used the unprojected b."""
    rng = np.random.default_rng(0)
    n = 6
    Q = rng.standard_normal((n, n))
    A = Q @ Q.T + n * np.eye(n)
    P = np.diag([0.0] + [1.0] * (n - 1))
    b = np.r_[1e6, 1e-9 * rng.standard_normal(n - 1)]
    Z = np.eye(n)[:, 1:]
    exact = Z @ np.linalg.solve(Z.T @ A @ Z, Z.T @ b)
    for solver in (pcg, pcr):
        res = solver(A, b, np.zeros(n), P=P, rtol=1e-8)
        assert res.converged and res.iterations > 0, res.reason
        assert np.linalg.norm(res.x - exact) <= 1e-8 * np.linalg.norm(exact)


@pytest.mark.parametrize("solver", [pcg, pcr])
def test_complex_operators_are_refused(solver):
    """A complex Hermitian A (or M) was cast to real with a ComplexWarning and reported converged, 30% off."""
    rng = np.random.default_rng(1)
    n = 8
    Z = rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))
    H = Z @ Z.conj().T + n * np.eye(n)
    b = rng.standard_normal(n)
    with pytest.raises(InputError, match="^A: complex operators are not supported"):
        solver(H, b)
    with pytest.raises(InputError, match="^M: complex operators are not supported"):
        solver(2.0 * np.eye(n), b, M=np.eye(n) * (1 + 1j))


def test_an_operator_returning_complex_values_is_refused():
    from scipy.sparse.linalg import LinearOperator

    n = 4
    op = LinearOperator((n, n), matvec=lambda v: (1 + 1j) * v, dtype=float)     # declares float, returns complex
    with pytest.raises(InputError, match="returned complex values"):
        pcg(op, np.ones(n))


def test_vectors_of_another_shape_are_refused():
    """b of shape (2, 5) for a 10 x 10 operator was flattened and solved (scipy's cg refuses it)."""
    A = np.diag(np.arange(1.0, 11.0))
    with pytest.raises(InputError, match=r"^b: has shape \(2, 5\), expected \(10,\), \(10, 1\) or \(1, 10\)"):
        pcg(A, np.ones((2, 5)))
    assert pcg(A, np.ones((10, 1))).converged


def test_restarted_pcg_keeps_its_lanczos_estimates():
    """After a restart the merged result had no cond, lambda_min, lambda_max; now the cycles' extreme Ritz
    values (inner estimates of the spectrum [1, 20])."""
    A = np.diag(np.arange(1.0, 21.0))
    res = PCG.restarted(A, np.ones(20), rtol=1e-10, maxiter=200, restart=5, cond=True)
    assert res.converged and res.restarts > 0
    assert 1.0 - 1e-12 <= res.lambda_min < 2.0 and 15.0 < res.lambda_max <= 20.0 + 1e-12
    assert res.cond == pytest.approx(res.lambda_max / res.lambda_min)


def test_a_diverging_inconsistent_system_does_not_blame_a_missing_preconditioner():
    res = pcg(np.diag([1.0, 2.0, 0.0]), np.ones(3))
    assert not res.converged and "the iterates diverge" in res.reason and "preconditioner" not in res.reason


@pytest.mark.parametrize("solver", [pcg, pcr])
def test_an_exact_x0_with_a_rotated_projection_is_accepted(solver):
    """A floor from ||P b|| + ||P A x0|| (a first fix of the x0 = 0 case) turned an exact x0 into a breakdown when P
    is not diagonal: the rounding of b - A x0, eps ||b||, reaches range(P). The floor is eps (||b|| + ||A x0||)
    again, and a zero x0 iterates as x0 = None (a review of the fix)."""
    rng = np.random.default_rng(0)
    n = 6
    Q = rng.standard_normal((n, n))
    A = Q @ Q.T + n * np.eye(n)
    V, _ = np.linalg.qr(rng.standard_normal((n, n)))
    Z = V[:, 1:]
    P = Z @ Z.T
    b = 1e6 * V[:, 0] + Z @ rng.standard_normal(n - 1)
    exact = Z @ np.linalg.solve(Z.T @ A @ Z, Z.T @ b)
    res = solver(A, b, exact, P=P, rtol=1e-8)
    assert res.converged and res.iterations == 0 and "x0 solves the system to rounding" in res.reason


def test_a_complex_preconditioner_is_named_and_real_values_of_complex_type_pass():
    from scipy.sparse.linalg import LinearOperator

    n = 4
    A = np.diag(np.arange(1.0, n + 1))
    M = LinearOperator((n, n), matvec=lambda v: (1 + 1j) * v, dtype=float)
    with pytest.raises(InputError, match="^M: the operator returned complex values"):
        pcg(A, np.ones(n), M=M)
    real_values = LinearOperator((n, n), matvec=lambda v: (v + 0j), dtype=float)     # an FFT-style M
    assert pcg(A, np.ones(n), M=real_values).converged


@pytest.mark.parametrize("solver", [pcg, pcr])
def test_a_nan_x0_fails_at_once(solver):
    """The zero-x0 test read NaN > 0 as false and iterated from b with the NaN left in x (40 iterations, then
    'non-finite iterate'); a NaN start fails at once, as before and as under MPI."""
    n = 5
    x0 = np.ones(n)
    x0[2] = np.nan
    res = solver(np.diag(np.arange(1.0, n + 1)), np.ones(n), x0)
    assert not res.converged and res.iterations == 0 and "non-finite initial residual" in res.reason


def test_an_fft_preconditioner_with_rounding_in_its_imaginary_part_passes():
    """An exact circulant inverse by numpy.fft has imaginary parts of about 1e-17: real values, accepted."""
    from scipy.sparse.linalg import LinearOperator

    n = 16
    c = np.zeros(n)
    c[[0, 1, -1]] = [2.5, -1.0, -1.0]                  # a circulant SPD matrix
    A = np.array([np.roll(c, k) for k in range(n)])
    eig = np.fft.fft(c)
    M = LinearOperator((n, n), matvec=lambda v: np.fft.ifft(np.fft.fft(v) / eig), dtype=float)
    res = pcg(A, np.arange(1.0, n + 1), M=M, rtol=1e-12)
    assert res.converged and res.iterations <= 2


@pytest.mark.parametrize("solver", [pcg, pcr])
def test_an_overflow_in_the_recurrence_is_a_quiet_breakdown(solver):
    """An overflow inside the iteration (a contact scene with rho 1e300 on every other subdomain) leaked numpy's
    'overflow encountered in dot' RuntimeWarning before the breakdown was reported; with warnings as errors
    the solve raised instead of returning converged=False."""
    import warnings

    A = np.diag([1e300, 1.0, 2.0])
    b = np.array([1e10, 1.0, 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = solver(A, b, rtol=1e-8, M=np.diag([1e300, 1e300, 1e300]))
    assert not res.converged and res.reason.startswith("breakdown:")
    assert "= inf" in res.reason or "non-finite" in res.reason, res.reason
