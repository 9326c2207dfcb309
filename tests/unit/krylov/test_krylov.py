"""Tests of ddsolve.krylov: PCG (Figure 1.2), PCR (Figure 1.3), Lanczos estimates."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from ddsolve.krylov import (PCR, RESTART_FACTOR, TRUE_RESIDUAL_FACTOR, KrylovResult, KrylovSolver, attained,
                            lanczos_extreme_eigenvalues, norm2, pcg, pcr)


# --------------------------------------------------------------------------- #
# problem builders
# --------------------------------------------------------------------------- #
def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def random_spd(rng: np.random.Generator, n: int, shift: float = 1.0) -> np.ndarray:
    q = rng.standard_normal((n, n))
    return q @ q.T / n + shift * np.eye(n)


def spd_with_spectrum(rng: np.random.Generator, eigs: np.ndarray) -> np.ndarray:
    u, _ = np.linalg.qr(rng.standard_normal((eigs.size, eigs.size)))
    a = u @ np.diag(eigs) @ u.T
    return (a + a.T) / 2


def laplacian_2d(m: int, rng: np.random.Generator) -> sp.csr_matrix:
    """5-point Laplacian on an m x m grid with a jumping positive coefficient."""
    n = m * m
    coef = np.exp(rng.uniform(-3.0, 3.0, size=n))  # wide range: Jacobi helps
    lap1 = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    eye = sp.identity(m)
    lap = sp.kron(eye, lap1) + sp.kron(lap1, eye)
    d = sp.diags(np.sqrt(coef))
    return sp.csr_matrix(d @ lap @ d)


def laplacian_1d(n: int) -> sp.csr_matrix:
    return sp.csr_matrix(sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)],
                                  [-1, 0, 1]))


def saddle_point(rng: np.random.Generator, nk: int = 40, m: int = 10):
    """[[K, B^T], [B, 0]] with K SPD, B full row rank, and a block preconditioner."""
    k = random_spd(rng, nk, shift=1.0) + np.diag(rng.uniform(0.0, 5.0, nk))
    bmat = rng.standard_normal((m, nk))
    a = np.block([[k, bmat.T], [bmat, np.zeros((m, m))]])
    # block-diagonal SPD preconditioner: Jacobi for K, exact Schur complement of
    # the Jacobi approximation for the multiplier block
    kinv_approx = np.diag(1.0 / np.diag(k))
    schur_approx = bmat @ kinv_approx @ bmat.T
    prec = sla.block_diag(kinv_approx, np.linalg.inv(schur_approx))
    return a, prec


def projector(rng: np.random.Generator, n: int, ncols: int = 3):
    g = rng.standard_normal((n, ncols))
    p = np.eye(n) - g @ np.linalg.solve(g.T @ g, g.T)
    return (p + p.T) / 2, g


# --------------------------------------------------------------------------- #
# PCG
# --------------------------------------------------------------------------- #
def test_pcg_random_spd_matches_direct_solve():
    rng = np.random.default_rng(0)
    a = random_spd(rng, 60)
    b = rng.standard_normal(60)
    res = pcg(a, b, rtol=1e-10)
    assert isinstance(res, KrylovResult)
    assert res.converged, res.reason
    assert res.reason.startswith("converged")
    assert _rel(res.x, np.linalg.solve(a, b)) < 1e-8
    assert res.residuals.shape == (res.iterations + 1,)
    assert res.residuals[-1] <= 1e-10 * res.residuals[0]
    assert res.true_residual == pytest.approx(res.residuals[-1], rel=1e-3)     # measured 1.4e-7 apart
    # x0 = None costs no matvec; one per iteration; one for the true residual
    assert res.matvecs == res.iterations + 1
    assert res.seconds >= 0.0
    assert res.lambda_min is None and res.lambda_max is None and res.cond is None


@pytest.mark.parametrize("wrap", ["sparse", "linop", "matvec_object"])
def test_pcg_laplacian_2d_jacobi(wrap):
    rng = np.random.default_rng(1)
    a = laplacian_2d(14, rng)
    n = a.shape[0]
    b = rng.standard_normal(n)
    x0 = rng.standard_normal(n)
    dinv = 1.0 / a.diagonal()
    if wrap == "sparse":
        aop, mop = a, sp.diags(dinv)
    elif wrap == "linop":
        aop = LinearOperator(a.shape, matvec=lambda v: a @ v, dtype=float)
        mop = LinearOperator(a.shape, matvec=lambda v: dinv * v, dtype=float)
    else:
        class Op:
            def __init__(self, f):
                self.shape = a.shape
                self.matvec = f
        aop, mop = Op(lambda v: a @ v), Op(lambda v: dinv * np.ravel(v))
    x_direct = np.linalg.solve(a.toarray(), b)
    res = pcg(aop, b, x0, rtol=1e-10, M=mop)
    assert res.converged, res.reason
    assert _rel(res.x, x_direct) < 1e-8
    assert res.matvecs == res.iterations + 2  # initial residual + true residual
    # Jacobi must pay off on this jumping-coefficient problem
    plain = pcg(a, b, x0, rtol=1e-10)
    assert plain.converged and res.iterations < plain.iterations


def test_pcg_1d_laplacian_and_callback():
    a = laplacian_1d(50)
    b = np.ones(50)
    seen: list[np.ndarray] = []
    res = pcg(a, b, rtol=1e-10, callback=lambda xk: seen.append(xk.copy()))
    assert res.converged
    assert len(seen) == res.iterations
    np.testing.assert_allclose(seen[-1], res.x)
    assert _rel(res.x, np.linalg.solve(a.toarray(), b)) < 1e-8
    assert res.iterations <= 26  # CG on the 1D Laplacian: n/2 steps for this b


def test_pcg_atol_and_zero_rhs():
    rng = np.random.default_rng(2)
    a = random_spd(rng, 20)
    zero = pcg(a, np.zeros(20), cond=True)
    assert zero.converged and zero.iterations == 0
    np.testing.assert_array_equal(zero.residuals, [0.0])
    np.testing.assert_array_equal(zero.x, np.zeros(20))
    assert zero.cond is None
    b = rng.standard_normal(20)
    res = pcg(a, b, rtol=0.0, atol=1e-3)
    assert res.converged and res.residuals[-1] <= 1e-3 < res.residuals[-2]


def test_pcg_maxiter_not_converged():
    a = laplacian_1d(200)
    b = np.random.default_rng(3).standard_normal(200)
    res = pcg(a, b, rtol=1e-10, maxiter=3)
    assert not res.converged
    assert "maxiter" in res.reason and res.reason.startswith("maxiter 3 reached")
    assert "> 1.0e-10" in res.reason
    assert len(res.residuals) == 4 and res.iterations == 3
    assert np.all(np.isfinite(res.x))


def test_pcg_default_maxiter_is_10n():
    a = laplacian_1d(30)
    b = np.random.default_rng(15).standard_normal(30)
    res = pcg(a, b, rtol=1e-300)  # unattainable
    assert not res.converged
    assert res.reason.startswith("maxiter 300 reached"), res.reason
    assert len(res.residuals) == 301


def test_pcg_breakdown_on_indefinite():
    a = np.diag([1.0, -2.0, 3.0])
    res = pcg(a, np.ones(3))
    assert not res.converged
    assert res.reason.startswith("breakdown")
    assert np.all(np.isfinite(res.x))
    assert np.all(np.isfinite(res.residuals))

    rng = np.random.default_rng(4)
    q, _ = np.linalg.qr(rng.standard_normal((30, 30)))
    indef = q @ np.diag(np.linspace(-1.0, 3.0, 30)) @ q.T
    res = pcg(indef, rng.standard_normal(30), rtol=1e-12, maxiter=500)
    assert not res.converged
    assert res.reason.startswith("breakdown"), res.reason
    assert np.all(np.isfinite(res.x))


def test_pcg_breakdown_non_spd_preconditioner_and_nan():
    rng = np.random.default_rng(5)
    a = random_spd(rng, 10)
    res = pcg(a, np.ones(10), M=-np.eye(10))
    assert not res.converged and res.reason.startswith("breakdown")
    b = np.ones(10)
    b[3] = np.nan
    res = pcg(a, b)
    assert not res.converged and res.reason.startswith("breakdown")
    assert np.all(np.isfinite(res.x))


# --------------------------------------------------------------------------- #
# Lanczos estimates
# --------------------------------------------------------------------------- #
def test_lanczos_unpreconditioned_extreme_eigenvalues():
    rng = np.random.default_rng(6)
    eigs = np.concatenate([[0.05], rng.uniform(1.0, 2.0, 38), [40.0]])
    a = spd_with_spectrum(rng, eigs)
    res = pcg(a, rng.standard_normal(40), rtol=1e-12, cond=True)
    assert res.converged
    ev = np.linalg.eigvalsh(a)
    assert res.lambda_min == pytest.approx(ev[0], rel=1e-6)
    assert res.lambda_max == pytest.approx(ev[-1], rel=1e-6)
    assert res.cond == pytest.approx(ev[-1] / ev[0], rel=1e-5)


def test_lanczos_preconditioned_matches_generalised_eigenvalues():
    rng = np.random.default_rng(7)
    n = 30
    mmat = random_spd(rng, n, shift=0.5)  # SPD inverse preconditioner
    lchol = np.linalg.cholesky(mmat)
    target = np.concatenate([[0.2], rng.uniform(2.0, 3.0, n - 2), [25.0]])
    # A = L^{-T} D L^{-1}  =>  M A = L D L^{-1} has spectrum D
    linv = np.linalg.inv(lchol)
    a = linv.T @ np.diag(target) @ linv
    a = (a + a.T) / 2
    res = pcg(a, rng.standard_normal(n), rtol=1e-12, M=mmat, cond=True)
    assert res.converged
    # eigenvalues of M A = generalised eigenvalues of (A, M^{-1})
    ev = sla.eigh(a, np.linalg.inv(mmat), eigvals_only=True)
    assert ev[0] == pytest.approx(0.2, rel=1e-8) and ev[-1] == pytest.approx(25.0, rel=1e-8)
    assert res.lambda_min == pytest.approx(ev[0], rel=1e-6)
    assert res.lambda_max == pytest.approx(ev[-1], rel=1e-6)
    assert res.cond == pytest.approx(125.0, rel=1e-5)


def test_lanczos_cond_false_leaves_none_and_early_stop_is_inner_estimate():
    rng = np.random.default_rng(8)
    a = spd_with_spectrum(rng, np.linspace(1.0, 100.0, 50))
    b = rng.standard_normal(50)
    off = pcg(a, b, rtol=1e-4)
    assert off.lambda_min is None and off.lambda_max is None and off.cond is None
    on = pcg(a, b, rtol=1e-4, cond=True)
    np.testing.assert_array_equal(on.x, off.x)  # recording changes nothing
    # Ritz values lie inside the spectrum
    assert 1.0 - 1e-10 <= on.lambda_min <= on.lambda_max <= 100.0 + 1e-8
    assert on.cond == pytest.approx(on.lambda_max / on.lambda_min)


def test_lanczos_function_direct():
    # one step: T = [1/alpha]
    assert lanczos_extreme_eigenvalues([0.5], []) == (2.0, 2.0)
    # extra betas are ignored; 2 x 2 case against a hand-built matrix
    alphas, betas = [0.5, 0.25], [0.09, 123.0]
    t = np.array([[2.0, 0.6], [0.6, 4.0 + 0.18]])
    ev = np.linalg.eigvalsh(t)
    lo, hi = lanczos_extreme_eigenvalues(alphas, betas)
    assert lo == pytest.approx(ev[0]) and hi == pytest.approx(ev[-1])
    with pytest.raises(ValueError):
        lanczos_extreme_eigenvalues([], [])
    with pytest.raises(ValueError):
        lanczos_extreme_eigenvalues([1.0, 2.0, 3.0], [0.1])


# --------------------------------------------------------------------------- #
# Projected PCG (FETI)
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("precondition", [False, True])
def test_projected_pcg(precondition):
    rng = np.random.default_rng(9)
    n = 40
    a = random_spd(rng, n)
    proj, g = projector(rng, n)
    b = proj @ rng.standard_normal(n)  # b in range(P)
    x0 = rng.standard_normal(n)
    mop = np.diag(1.0 / np.diag(a)) if precondition else None
    res = pcg(a, b, x0, rtol=1e-12, M=mop, P=proj, cond=True)
    assert res.converged, res.reason
    assert np.linalg.norm(proj @ (a @ res.x) - proj @ b) <= 1e-10 * np.linalg.norm(b)
    assert np.linalg.norm(g.T @ (res.x - x0)) <= 1e-10 * np.linalg.norm(x0)
    # compare with the direct solve on range(P): x = x0 + Z y, Z^T A Z y = Z^T (b - A x0)
    z = sla.null_space(g.T)
    y = np.linalg.solve(z.T @ a @ z, z.T @ (b - a @ x0))
    assert _rel(res.x, x0 + z @ y) < 1e-9
    assert res.true_residual <= 100 * res.residuals[-1] + 1e-14
    # the Lanczos estimates refer to P M P A on range(P)
    mz = np.eye(n) if mop is None else mop
    ev = sla.eigh(z.T @ a @ z, np.linalg.inv(z.T @ mz @ z), eigvals_only=True)
    assert ev[0] * (1 - 1e-6) <= res.lambda_min and res.lambda_max <= ev[-1] * (1 + 1e-6)
    assert res.lambda_max == pytest.approx(ev[-1], rel=1e-4)


# --------------------------------------------------------------------------- #
# PCR
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("precondition", [False, True])
def test_pcr_saddle_point(precondition):
    rng = np.random.default_rng(10)
    a, prec = saddle_point(rng)
    f = rng.standard_normal(a.shape[0])
    x_direct = sla.solve(a, f)
    res = pcr(a, f, rtol=1e-12, M=prec if precondition else None)
    assert res.converged, res.reason
    assert _rel(res.x, x_direct) < 1e-8
    assert res.residuals.shape == (res.iterations + 1,)
    assert res.residuals[-1] <= 1e-12 * res.residuals[0]
    assert res.true_residual <= 100 * res.residuals[-1]
    assert res.lambda_min is None and res.cond is None


def test_pcr_preconditioner_pays_off_and_operator_types():
    rng = np.random.default_rng(11)
    a, prec = saddle_point(rng, nk=60, m=15)
    f = rng.standard_normal(a.shape[0])
    plain = pcr(a, f, rtol=1e-8)
    aop = LinearOperator(a.shape, matvec=lambda v: a @ v, dtype=float)
    pre = pcr(aop, f, rtol=1e-8, M=sp.csr_matrix(prec))
    assert plain.converged and pre.converged
    assert pre.iterations < plain.iterations
    assert _rel(pre.x, sla.solve(a, f)) < 1e-6


def test_pcr_spd_and_x0():
    rng = np.random.default_rng(12)
    a = laplacian_2d(8, rng)
    b = rng.standard_normal(a.shape[0])
    x0 = rng.standard_normal(a.shape[0])
    seen = []
    res = pcr(a, b, x0, rtol=1e-11, M=sp.diags(1.0 / a.diagonal()), callback=seen.append)
    assert res.converged
    assert len(seen) == res.iterations
    assert _rel(res.x, np.linalg.solve(a.toarray(), b)) < 1e-8


def test_pcr_zero_cr_pivot_uses_three_term_recurrence():
    # <z0, A z0> = 0: the two-term CR recurrences cannot start; Figure 1.3 can
    a = np.diag([1.0, -1.0, 2.0, -2.0])
    b = np.ones(4)
    res = pcr(a, b, rtol=1e-12)
    assert res.converged, res.reason
    np.testing.assert_allclose(res.x, [1.0, -1.0, 0.5, -0.5], rtol=1e-12)
    # spectrum {+-1, +-2}: the residual polynomial needs degree 4 (odd steps stagnate)
    assert res.iterations == 4


def test_pcr_projected():
    rng = np.random.default_rng(13)
    a, prec = saddle_point(rng, nk=30, m=8)
    n = a.shape[0]
    proj, g = projector(rng, n)
    f = proj @ rng.standard_normal(n)
    x0 = rng.standard_normal(n)
    res = pcr(a, f, x0, rtol=1e-12, M=prec, P=proj)
    assert res.converged, res.reason
    assert np.linalg.norm(proj @ (a @ res.x) - f) <= 1e-10 * np.linalg.norm(f)
    assert np.linalg.norm(g.T @ (res.x - x0)) <= 1e-10 * np.linalg.norm(x0)
    z = sla.null_space(g.T)
    y = np.linalg.solve(z.T @ a @ z, z.T @ (f - a @ x0))
    assert _rel(res.x, x0 + z @ y) < 1e-8


def test_pcr_maxiter_and_breakdown():
    rng = np.random.default_rng(14)
    a, _ = saddle_point(rng, nk=60, m=15)
    f = rng.standard_normal(a.shape[0])
    res = pcr(a, f, rtol=1e-12, maxiter=3)
    assert not res.converged
    assert "maxiter" in res.reason and len(res.residuals) == 4
    # singular operator: <A p, M A p> = 0
    sing = pcr(np.zeros((5, 5)), np.ones(5))
    assert not sing.converged and sing.reason.startswith("breakdown")
    assert np.all(np.isfinite(sing.x))
    # preconditioner that is not positive definite
    neg = pcr(a, f, M=-np.eye(a.shape[0]))
    assert not neg.converged and neg.reason.startswith("breakdown")
    # NaN in the operator output
    bad = LinearOperator(a.shape, matvec=lambda v: np.full(a.shape[0], np.nan), dtype=float)
    res = pcr(bad, f)
    assert not res.converged and res.reason.startswith("breakdown")
    assert np.all(np.isfinite(res.x))


# --------------------------------------------------------------------------- #
# argument validation
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("solver", [pcg, pcr])
def test_invalid_arguments(solver):
    a = np.eye(4)
    b = np.ones(4)
    with pytest.raises(ValueError, match="b"):
        solver(a, np.ones(5))
    with pytest.raises(ValueError, match="x0"):
        solver(a, b, np.ones(3))
    with pytest.raises(ValueError, match="square"):
        solver(np.ones((4, 3)), b)
    with pytest.raises(ValueError, match="M"):
        solver(a, b, M=np.eye(3))
    with pytest.raises(ValueError, match="P"):
        solver(a, b, P=np.eye(5))
    with pytest.raises(ValueError, match="rtol"):
        solver(a, b, rtol=0.0, atol=0.0)
    with pytest.raises(ValueError, match="rtol"):
        solver(a, b, rtol=-1.0)
    with pytest.raises(ValueError, match="maxiter"):
        solver(a, b, maxiter=0)
    with pytest.raises(ValueError, match="A"):
        solver("not an operator", b)
    # rtol = 0 with atol > 0 is fine
    assert solver(a, b, rtol=0.0, atol=1e-12).converged


@pytest.mark.parametrize("pivot_tol", [1.0, 0.1])
@pytest.mark.parametrize("precondition", [False, True])
def test_pcr_three_term_recurrence_figure_1_3(monkeypatch, caplog, pivot_tol, precondition):
    """Force the hand-over to the Figure 1.3 recurrence: at the start (pivot_tol=1)
    or in mid-run (pivot_tol=0.1 trips after a few CR steps on this problem)."""
    import importlib
    import logging

    pcr_module = importlib.import_module("ddsolve.krylov.pcr")
    monkeypatch.setattr(pcr_module, "_CR_PIVOT_TOL", pivot_tol)
    rng = np.random.default_rng(10)
    a, prec = saddle_point(rng)
    f = rng.standard_normal(a.shape[0])
    with caplog.at_level(logging.DEBUG, logger="ddsolve.krylov.pcr"):
        res = pcr(a, f, rtol=1e-12, M=prec if precondition else None)
    switches = [r.getMessage() for r in caplog.records if "switching" in r.getMessage()]
    assert len(switches) == 1
    if pivot_tol < 1.0:
        assert "at iteration 1," not in switches[0]
    assert res.converged, res.reason
    assert _rel(res.x, sla.solve(a, f)) < 1e-8
    assert res.true_residual <= 100 * res.residuals[-1]


# --------------------------------------------------------------------------- #
# base class, convergence policy, scale safety
# --------------------------------------------------------------------------- #
class _Richardson(KrylovSolver):
    """x += omega r: the smallest recurrence, to show what the base class does."""

    name = "richardson"

    def __init__(self, *args, omega: float = 1.0, **kwargs):
        super().__init__(*args, **kwargs)
        self.omega = omega

    def iterate(self) -> str:
        while True:
            self.x += self.omega * self.r
            self.r = self.b - self.op(self.x)
            outcome = self.advance(norm2(self.r))
            if outcome is not None:
                return outcome


def test_base_class_does_the_bookkeeping():
    a = np.diag(np.linspace(0.5, 1.5, 12))
    b = np.random.default_rng(20).standard_normal(12)
    seen = []
    res = _Richardson(a, b, rtol=1e-8, callback=lambda xk: seen.append(xk.copy())).solve()
    assert res.converged and res.attained and res.restarts == 0
    assert res.iterations == len(seen) == len(res.residuals) - 1
    assert res.matvecs == res.iterations + 1                      # + the recomputed residual
    assert res.true_residual == pytest.approx(np.linalg.norm(b - a @ res.x), rel=1e-12)
    assert res.residuals[-1] <= 1e-8 * res.residuals[0] < res.residuals[-2]
    np.testing.assert_allclose(res.x, b / np.diag(a), rtol=1e-7)
    slow = _Richardson(a, b, rtol=1e-8, maxiter=3).solve()
    assert not slow.converged and slow.reason.startswith("maxiter 3 reached") and slow.iterations == 3


@pytest.mark.parametrize("solver", [pcg, pcr])
def test_zero_rhs_gives_zero_solution(solver):
    rng = np.random.default_rng(21)
    a = random_spd(rng, 15)
    res = solver(a, np.zeros(15), x0=rng.standard_normal(15))
    assert res.converged and res.iterations == 0 and res.attained
    np.testing.assert_array_equal(res.x, np.zeros(15))
    assert "zero right-hand side" in res.reason
    assert res.true_residual == 0.0


@pytest.mark.parametrize("solver", [pcg, pcr])
def test_non_finite_true_residual_is_not_converged(solver):
    """The recursion converges but the operator returns NaN for the recomputed residual."""
    rng = np.random.default_rng(22)
    a = random_spd(rng, 10)
    n_iter = solver(a, np.ones(10), rtol=1e-8).iterations
    calls = []

    def matvec(v):
        calls.append(1)
        return a @ v if len(calls) <= n_iter else np.full(10, np.nan)

    res = solver(LinearOperator(a.shape, matvec=matvec, dtype=float), np.ones(10), rtol=1e-8)
    assert res.iterations == n_iter and not res.converged
    assert res.reason.startswith("non-finite"), res.reason
    assert res.attained is False


@pytest.mark.parametrize("solver", [pcg, pcr])
def test_non_finite_data_reported(solver):
    a = random_spd(np.random.default_rng(23), 10)
    b = np.ones(10)
    b[2] = np.inf
    res = solver(a, b)
    assert not res.converged and "non-finite" in res.reason


def test_tolerance_below_attainable_accuracy_is_not_converged():
    rng = np.random.default_rng(24)
    a = spd_with_spectrum(rng, np.logspace(0, 8, 60))
    res = pcg(a, rng.standard_normal(60), rtol=1e-20, maxiter=2000)
    assert not res.converged and res.attained is False
    assert res.reason.startswith("tolerance not attained") or res.reason.startswith("maxiter")
    assert attained(res, 1e-20)[0] is False


def test_attained_matches_the_api_rule():
    rng = np.random.default_rng(25)
    a = random_spd(rng, 20)
    res = pcg(a, rng.standard_normal(20), rtol=1e-8)
    assert attained(res, 1e-8) == (True, res.reason)
    # a converged result whose recomputed residual misses rtol by more than the factor
    bad = KrylovResult(x=res.x, converged=True, reason="converged", iterations=3,
                       residuals=np.array([1.0, 1e-9]), true_residual=2 * TRUE_RESIDUAL_FACTOR * 1e-8)
    ok, why = attained(bad, 1e-8)
    assert not ok and why.startswith("tolerance not attained")
    assert RESTART_FACTOR < TRUE_RESIDUAL_FACTOR


# powers of two near 1e170, 1e-170, 1e300, 1e-300: the scaled systems are exact, so the
# iterates must be the same numbers (the solvers rescale by powers of two internally)
POW2 = [2.0 ** 565, 2.0 ** -565, 2.0 ** 996, 2.0 ** -996]


@pytest.mark.parametrize("scale", POW2)
@pytest.mark.parametrize("solver", ["pcg", "pcr-l2", "pcr-M"])
def test_scaled_systems_same_iterations(solver, scale):
    """b -> scale b: ||b||^2 under/overflows at these scales; same iterations, x -> scale x."""
    rng = np.random.default_rng(26)
    a = laplacian_2d(8, rng)
    m = sp.diags(1.0 / a.diagonal())
    b = rng.standard_normal(a.shape[0])
    run = {"pcg": lambda bb, **k: pcg(a, bb, M=m, rtol=1e-10, **k),
           "pcr-l2": lambda bb, **k: pcr(a, bb, M=m, rtol=1e-10, **k),
           "pcr-M": lambda bb, **k: pcr(a, bb, M=m, rtol=1e-10, norm="M", **k)}[solver]
    ref = run(b)
    seen = []
    res = run(scale * b, callback=lambda xk: seen.append(float(np.abs(xk).max())))
    assert ref.converged and res.converged, res.reason
    assert res.iterations == ref.iterations > 5
    np.testing.assert_array_equal(res.x, scale * ref.x)
    np.testing.assert_array_equal(res.residuals, scale * ref.residuals)
    assert res.true_residual == scale * ref.true_residual
    # the callback sees the unscaled iterate
    assert seen[-1] == scale * float(np.abs(ref.x).max())


@pytest.mark.parametrize("scale", [2.0 ** 565, 2.0 ** -565])
def test_scaled_operator_same_iterations(scale):
    """A -> A / scale, b -> b / scale (rho ~ 1e-170 / 1e170 with x ~ 1): ||r0||^2 under/overflows;
    the same iterates (was 'converged: ||r0|| = 0' after 0 iterations, or a breakdown)."""
    rng = np.random.default_rng(27)
    a = laplacian_2d(8, rng)
    m = sp.diags(1.0 / a.diagonal())
    b = rng.standard_normal(a.shape[0])
    ref = pcg(a, b, M=m, rtol=1e-9)
    res = pcg(a / scale, b / scale, M=m * scale, rtol=1e-9)
    assert res.converged and res.iterations == ref.iterations > 5
    np.testing.assert_array_equal(res.x, ref.x)


def test_norm2_safe_and_fast_path_exact():
    v = np.random.default_rng(28).standard_normal(1000)
    assert norm2(v) == np.sqrt(np.dot(v, v))              # fast path: the same number as before
    assert norm2(1e-170 * v) == pytest.approx(1e-170 * norm2(v), rel=1e-14)
    assert norm2(1e170 * v) == pytest.approx(1e170 * norm2(v), rel=1e-14)
    assert norm2(np.zeros(3)) == 0.0 and norm2(np.zeros(0)) == 0.0
    assert np.isnan(norm2(np.array([1.0, np.nan]))) and norm2(np.array([1.0, np.inf])) == np.inf


def test_restarted_counts_restarts_and_matches_one_cycle():
    rng = np.random.default_rng(29)
    a, _ = saddle_point(rng, nk=60, m=15)
    f = rng.standard_normal(a.shape[0])
    one = pcr(a, f, rtol=1e-10, maxiter=2000)
    res = PCR.restarted(a, f, rtol=1e-10, maxiter=2000, restart=10)
    assert one.converged and res.converged and res.attained
    assert res.restarts >= 1 and res.iterations > 10 * res.restarts
    assert len(res.residuals) == res.iterations + 1
    assert "restart" in res.reason
    np.testing.assert_allclose(res.x, np.linalg.solve(a, f), rtol=1e-7, atol=1e-9)
    single = PCR.restarted(a, f, rtol=1e-10, maxiter=2000, restart=2000)
    assert single.restarts == 0 and single.iterations == one.iterations
    np.testing.assert_array_equal(single.x, one.x)


def test_a_restarted_solve_states_its_reason_for_the_whole_solve():
    """The last cycle's reason was relative to its own r_0 and budget ('maxiter 100 reached: ... > 2.9e-14'
    for maxiter 1000 and rtol 1e-6, a review); the reason now names the solve's maxiter and rtol."""
    from ddsolve.krylov.pcg import PCG

    n = 60
    A = np.diag(np.geomspace(1.0, 1e6, n))
    b = np.random.default_rng(0).standard_normal(n)
    res = PCG.restarted(A, b, rtol=1e-12, maxiter=12, restart=5)
    assert not res.converged and res.iterations == 12 and res.restarts == 2
    ratio = np.linalg.norm(b - A @ res.x) / np.linalg.norm(b)
    head, rest = res.reason.split(": ||r||/||r0|| = ")
    assert head == "maxiter 12 reached"
    assert rest.endswith("> 1.0e-12 after 2 restart(s) of at most 5 iterations")
    assert float(rest.split()[0]) == pytest.approx(ratio, rel=0.05)
    done = PCG.restarted(np.diag(np.geomspace(1.0, 100.0, n)), b, rtol=1e-6, maxiter=200, restart=5)
    assert done.converged and done.restarts >= 1
    assert done.reason.startswith("converged: ||r||/||r0|| = ") and "<= 1.0e-06 after" in done.reason


@pytest.mark.parametrize("solver", [pcg, pcr])
@pytest.mark.parametrize("scale", [1.0, 1e150])     # 1e150: the run is rescaled (r0 ~ 1e136)
def test_x0_that_solves_the_system_to_rounding_is_accepted(solver, scale):
    """An x0 from a direct solve has ||r0|| at rounding: the rule rtol ||r0|| is then below rounding and
    was reported "tolerance not attained" after useless iterations; it is converged before the first step."""
    rng = np.random.default_rng(11)
    a = laplacian_2d(12, rng)
    b = a @ rng.standard_normal(a.shape[0]) * scale
    x_direct = sp.linalg.spsolve(a.tocsc(), b)
    r0 = np.linalg.norm(b - a @ x_direct)
    assert 0 < r0 < 64 * np.finfo(float).eps * 2 * np.linalg.norm(b)       # a rounding-level residual
    res = solver(a, b, x_direct, rtol=1e-8)
    assert res.converged and res.iterations == 0 and res.reason.startswith("converged: x0 solves the system")
    assert np.array_equal(res.x, x_direct) and res.true_residual == pytest.approx(r0, rel=1e-12)
    # a guess off by more than rounding still iterates to the relative rule
    near = x_direct + 1e-6 * np.linalg.norm(x_direct) / np.sqrt(x_direct.size)
    res = solver(a, b, near, rtol=1e-6)
    assert res.converged and res.iterations > 0 and _rel(res.x, x_direct) < 1e-9


def test_x0_at_rounding_with_a_projection_is_accepted():
    """The FETI case: r0 = P (b - A x0) at rounding for an x0 solving the projected system."""
    rng = np.random.default_rng(12)
    n, k = 40, 3
    a = random_spd(rng, n)
    g = rng.standard_normal((n, k))
    q, _ = np.linalg.qr(g)
    proj = np.eye(n) - q @ q.T
    b = proj @ rng.standard_normal(n)
    z = sla.null_space(q.T)
    x = z @ np.linalg.solve(z.T @ a @ z, z.T @ b)
    res = pcg(a, b, x, rtol=1e-10, P=proj)
    assert res.converged and res.iterations == 0 and "to rounding" in res.reason
