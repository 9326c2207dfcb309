"""Tests of the bound/equality constrained QP solvers MPRGP (Figure 6.6) and SMALBE (Figure 6.7).

Solutions are compared with independent references: exhaustive active-set enumeration
(KKT systems for every active set) for n <= 10, and SLSQP with tight tolerances for
larger n; the KKT conditions of the returned solutions are checked directly.
"""
from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.optimize as so
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from ddsolve.errors import InputError
from ddsolve.qp import QPResult, estimate_norm, mprgp, smalbe


# --------------------------------------------------------------------------- generators
def spd(rng: np.random.Generator, n: int, lo: float = 1.0, hi: float = 100.0, n_zero: int = 0) -> np.ndarray:
    """Random symmetric matrix with eigenvalues in [lo, hi] (plus ``n_zero`` zeros)."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    ev = rng.uniform(lo, hi, n)
    ev[:n_zero] = 0.0
    A = (Q * ev) @ Q.T
    return 0.5 * (A + A.T)


def bound_problem(seed: int, n: int, frac_free: float = 0.25):
    """Strictly convex bound constrained QP with a mix of active/inactive and -inf bounds."""
    rng = np.random.default_rng(seed)
    A = spd(rng, n)
    b = 20.0 * rng.standard_normal(n)
    lb = rng.standard_normal(n)
    lb[rng.random(n) < frac_free] = -np.inf
    return A, b, lb


def be_problem(seed: int, n: int, m: int, n_zero: int = 0, frac_free: float = 0.25):
    """Convex QP with bounds and m equalities; A may be PSD (PD on ker(BE))."""
    rng = np.random.default_rng(seed)
    A = spd(rng, n, n_zero=n_zero)
    b = 20.0 * rng.standard_normal(n)
    lb = rng.standard_normal(n)
    lb[rng.random(n) < frac_free] = -np.inf
    B = rng.standard_normal((m, n))
    x_feas = np.where(np.isfinite(lb), lb, 0.0) + rng.uniform(0.0, 1.0, n)
    c = B @ x_feas
    return A, b, lb, B, c


# --------------------------------------------------------------------------- references
def enumerate_bound(A, b, lb):
    """Exact minimiser of 1/2 x'Ax - b'x s.t. x >= lb by trying every active set."""
    n = len(b)
    bounded = np.flatnonzero(np.isfinite(lb))
    best, best_viol = None, np.inf
    for k in range(len(bounded) + 1):
        for S in itertools.combinations(bounded, k):
            S = np.array(S, dtype=int)
            F = np.setdiff1d(np.arange(n), S)
            x = np.where(np.isfinite(lb), lb, 0.0)
            if len(F):
                x[F] = np.linalg.solve(A[np.ix_(F, F)], b[F] - A[np.ix_(F, S)] @ lb[S])
            g = A @ x - b
            viol = max(np.max(lb - x, initial=0.0), np.max(-g[S], initial=0.0))
            if viol < best_viol:
                best, best_viol = x, viol
    assert best_viol < 1e-9 * (1 + np.abs(b).max())
    return best


def enumerate_be(A, b, lb, B, c):
    """Exact minimiser (and multiplier) of the bound and equality constrained QP."""
    n, m = len(b), len(c)
    bounded = np.flatnonzero(np.isfinite(lb))
    best, best_viol = None, np.inf
    for k in range(len(bounded) + 1):
        for S in itertools.combinations(bounded, k):
            S = np.array(S, dtype=int)
            s = len(S)
            E = np.zeros((n, s))
            E[S, np.arange(s)] = 1.0
            K = np.block([[A, B.T, -E], [B, np.zeros((m, m + s))], [E.T, np.zeros((s, m + s))]])
            rhs = np.concatenate([b, c, lb[S]])
            if np.linalg.matrix_rank(K) < n + m + s:
                continue
            sol = np.linalg.solve(K, rhs)
            x, mu, nu = sol[:n], sol[n:n + m], sol[n + m:]
            viol = max(np.max(lb - x, initial=0.0), np.max(-nu, initial=0.0))
            if viol < best_viol:
                best, best_viol = (x, mu), viol
    assert best_viol < 1e-9 * (1 + np.abs(b).max())
    return best


def slsqp(A, b, lb, B=None, c=None):
    """Reference solution: SLSQP with tight tolerances, polished by one active-set solve.

    SLSQP alone is accurate to about 1e-6 (and may stop on a line-search failure); its active set (bounds met within 1e-7) is used to
    solve the equality-constrained KKT system exactly, and the polished point is accepted
    only if it satisfies all KKT conditions (otherwise the raw SLSQP point is returned).
    """
    n = len(b)
    bounds = [(float(l) if np.isfinite(l) else None, None) for l in lb]
    cons = []
    if B is not None:
        cons = [{"type": "eq", "fun": lambda x: B @ x - c, "jac": lambda x: B}]
    x0 = np.where(np.isfinite(lb), lb, 0.0) + 1.0
    out = so.minimize(lambda x: 0.5 * x @ A @ x - b @ x, x0, jac=lambda x: A @ x - b,
                      bounds=bounds, constraints=cons, method="SLSQP",
                      options={"ftol": 1e-12, "maxiter": 2000})
    S = np.flatnonzero(np.isfinite(lb) & (out.x - lb <= 1e-7 * (1 + np.abs(out.x).max())))
    m = 0 if B is None else B.shape[0]
    s = len(S)
    E = np.zeros((n, s))
    E[S, np.arange(s)] = 1.0
    Bm = np.zeros((0, n)) if B is None else B
    cm = np.zeros(0) if B is None else c
    K = np.block([[A, Bm.T, -E], [Bm, np.zeros((m, m + s))], [E.T, np.zeros((s, m + s))]])
    try:
        sol = np.linalg.solve(K, np.concatenate([b, cm, lb[S]]))
    except np.linalg.LinAlgError:
        sol = None
    if sol is not None:
        x, nu = sol[:n], sol[n + m:]
        tol = 1e-10 * (1 + np.abs(b).max())
        if np.all(x >= lb - tol) and np.all(nu >= -tol):
            return np.maximum(x, lb)
    assert out.success, out.message
    return out.x


def assert_kkt(A, b, lb, x, tol, B=None, c=None, mu=None):
    """KKT conditions (6.7)-(6.8) (with BE^T mu added for equality constraints)."""
    g = A @ x - b
    if B is not None:
        g = g + B.T @ mu
        assert np.linalg.norm(B @ x - c) <= tol
    assert np.all(x >= lb)                                   # feasibility (exact: projections)
    active = x == lb
    assert np.all(g[active] >= -tol)                         # g_i >= 0 on active bounds
    assert np.all(np.abs(g[~active]) <= tol)                 # g_i = 0 on free variables
    fin = np.isfinite(lb)
    assert np.all(np.abs(g[fin] * (x[fin] - lb[fin])) <= tol * (1 + np.abs(x[fin] - lb[fin])))


def assert_counters(res: QPResult):
    assert res.n_hessian > 0
    assert res.n_cg + res.n_expansion + res.n_proportioning == res.iterations


# --------------------------------------------------------------------------- MPRGP
@pytest.mark.parametrize("n", [5, 7, 10])
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("halfstep", [True, False])
def test_mprgp_matches_enumeration(n, seed, halfstep):
    A, b, lb = bound_problem(seed, n)
    res = mprgp(A, b, lb, rtol=1e-11, halfstep=halfstep)
    assert res.converged, res.reason
    x_ref = enumerate_bound(A, b, lb)
    np.testing.assert_allclose(res.x, x_ref, rtol=0, atol=1e-8 * np.abs(x_ref).max())
    assert_kkt(A, b, lb, res.x, tol=1e-9 * np.linalg.norm(b))
    assert_counters(res)
    assert res.gradient_norms.shape == (res.iterations + 1,)
    assert res.gradient_norms[-1] <= 1e-11 * np.linalg.norm(b)


@pytest.mark.parametrize("n", [20, 30, 40])
def test_mprgp_matches_slsqp(n):
    A, b, lb = bound_problem(100 + n, n)
    res = mprgp(A, b, lb, rtol=1e-12)
    assert res.converged, res.reason
    x_ref = slsqp(A, b, lb)
    np.testing.assert_allclose(res.x, x_ref, rtol=0, atol=1e-6 * np.abs(x_ref).max())
    assert_kkt(A, b, lb, res.x, tol=1e-10 * np.linalg.norm(b))
    assert_counters(res)
    assert res.n_expansion + res.n_proportioning > 0     # bounds are really active
    # the reference is not better than MPRGP's solution
    f = lambda x: 0.5 * x @ A @ x - b @ x
    assert f(res.x) <= f(x_ref) + 1e-9 * abs(f(x_ref))


def test_mprgp_monotone_cost_and_rtol_rule():
    A, b, lb = bound_problem(7, 30)
    res = mprgp(A, b, lb, rtol=1e-5)
    assert res.converged
    assert res.gradient_norms[-1] <= 1e-5 * np.linalg.norm(b)
    assert res.gradient_norms[-2] > 1e-5 * np.linalg.norm(b)  # stopped at the first success
    assert "converged" in res.reason


def test_mprgp_unconstrained_is_cg():
    rng = np.random.default_rng(3)
    n = 25
    A = spd(rng, n)
    b = rng.standard_normal(n)
    res = mprgp(A, b, np.full(n, -np.inf), rtol=1e-12, norm_A=np.linalg.norm(A, 2))
    assert res.converged
    np.testing.assert_allclose(res.x, np.linalg.solve(A, b), rtol=1e-9, atol=1e-12)
    assert res.n_expansion == 0 and res.n_proportioning == 0 and res.n_cg == res.iterations
    assert res.n_hessian == res.iterations + 2            # A x0, one per CG step, the recomputed gradient at the end
    assert res.iterations <= n + 5


def test_mprgp_operator_types_and_x0():
    A, b, lb = bound_problem(11, 15)
    ref = mprgp(A, b, lb, rtol=1e-12)
    op = LinearOperator(A.shape, matvec=lambda v: A @ v, dtype=float)
    for AA in (sp.csr_matrix(A), op):
        res = mprgp(AA, b, lb, rtol=1e-12)
        assert res.converged
        np.testing.assert_allclose(res.x, ref.x, atol=1e-9 * np.abs(ref.x).max())
    # infeasible x0 is projected, not rejected
    x0 = np.where(np.isfinite(lb), lb, 0.0) - 5.0
    res = mprgp(A, b, lb, x0=x0, rtol=1e-12)
    assert res.converged
    np.testing.assert_allclose(res.x, ref.x, atol=1e-9 * np.abs(ref.x).max())
    # warm start at the solution: no steps needed
    res = mprgp(A, b, lb, x0=ref.x, rtol=1e-10, norm_A=np.linalg.norm(A, 2))
    assert res.converged and res.iterations == 0 and res.n_hessian == 1


def test_mprgp_alpha_gamma_variants():
    A, b, lb = bound_problem(5, 20)
    norm = np.linalg.norm(A, 2)
    x_ref = slsqp(A, b, lb)
    for Gamma, alpha in [(0.1, 1.0 / norm), (1.0, 2.0 / norm), (10.0, 0.5 / norm)]:
        res = mprgp(A, b, lb, Gamma=Gamma, alpha=alpha, norm_A=norm, rtol=1e-12)
        assert res.converged, (Gamma, alpha, res.reason)
        assert res.alpha == alpha
        np.testing.assert_allclose(res.x, x_ref, atol=1e-6 * np.abs(x_ref).max())
        assert_counters(res)


def test_mprgp_tol_overrides():
    A, b, lb = bound_problem(9, 12)
    res = mprgp(A, b, lb, tol=1e-3)
    assert res.converged and res.gradient_norms[-1] <= 1e-3
    calls = []

    def rule(x, gp):
        calls.append(gp)
        return "custom" if gp <= 1e-6 else None

    res = mprgp(A, b, lb, tol=rule)
    # once before every step and at the end, and once more to confirm the stop with the recomputed gradient
    assert res.converged and res.reason == "custom" and len(calls) == res.iterations + 2
    assert calls[-1] <= 1e-6                      # the recomputed norm / 10, accepted by the rule


def test_mprgp_maxiter_returns_unconverged():
    A, b, lb = bound_problem(4, 30)
    res = mprgp(A, b, lb, rtol=1e-12, maxiter=2)
    assert not res.converged
    assert res.iterations == 2
    assert "maxiter" in res.reason and "\n" not in res.reason
    assert np.all(res.x >= lb)
    res = mprgp(A, b, lb, maxiter=0)
    assert not res.converged and res.iterations == 0


def test_mprgp_unbounded_reports_breakdown():
    # A = 0 on the second coordinate, b pushes it to +inf: unbounded below, no exception
    A = np.diag([1.0, 0.0])
    res = mprgp(A, np.array([1.0, 1.0]), np.array([0.0, 0.0]), norm_A=1.0, maxiter=50)
    assert not res.converged and "breakdown" in res.reason


@pytest.mark.parametrize("kwargs, name", [
    ({"Gamma": 0.0}, "Gamma"),
    ({"Gamma": -1.0}, "Gamma"),
    ({"alpha": 0.0}, "alpha"),
    ({"alpha": 2.5, "norm_A": 1.0}, "alpha"),
    ({"norm_A": -1.0}, "norm_A"),
    ({"rtol": -1.0}, "rtol"),
    ({"maxiter": -1}, "maxiter"),
    ({"x0": np.zeros(3)}, "x0"),
])
def test_mprgp_bad_arguments(kwargs, name):
    A = np.eye(4)
    with pytest.raises(ValueError, match=name):
        mprgp(A, np.ones(4), np.zeros(4), **kwargs)


def test_mprgp_bad_shapes():
    with pytest.raises(ValueError, match="A"):
        mprgp(np.eye(3), np.ones(4), np.zeros(4))
    with pytest.raises(ValueError, match="lb"):
        mprgp(np.eye(4), np.ones(4), np.zeros(3))
    with pytest.raises(ValueError, match="lb"):
        mprgp(np.eye(4), np.ones(4), np.array([0.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="b"):
        mprgp(np.eye(4), np.array([1.0, np.inf, 0.0, 0.0]), 0.0)


@pytest.mark.parametrize("n", [30, 60, 200])
def test_estimate_norm(n):
    """Seeded Lanczos (dense below DENSE_MAX): ||A||_2 to ~1e-6, a lower bound, deterministic."""
    rng = np.random.default_rng(0)
    A = spd(rng, n)
    est, k = estimate_norm(A)
    exact = np.linalg.norm(A, 2)
    assert exact * (1 - 1e-6) <= est <= exact * (1 + 1e-12) and 0 < k <= max(n, 200)
    assert estimate_norm(A, seed=0) == estimate_norm(A, seed=0)  # deterministic
    assert estimate_norm(np.zeros((n, n)))[0] == 0.0


def test_estimate_norm_clustered_top_is_cheap():
    """A cluster of 200 eigenvalues in [0.99, 1] under 1,800 in [0, 0.5]: the default tolerance gives
    ||A|| to 1e-4 from below in at most 100 products (tol = 1e-6 needs 441 here, and 2,221 on the
    preconditioner of (5.4) at 1M dofs)."""
    rng = np.random.default_rng(0)
    d = np.concatenate([1.0 - 0.01 * rng.random(200), 0.5 * rng.random(1800)])
    d[0] = 1.0
    est, k = estimate_norm(sp.diags(d))
    assert 1.0 - 1e-4 <= est <= 1.0 + 1e-12 and k <= 100
    fine, k_fine = estimate_norm(sp.diags(d), tol=1e-6)
    assert abs(fine - 1.0) <= 1e-8 and k_fine > 4 * k


# --------------------------------------------------------------------------- SMALBE
@pytest.mark.parametrize("n, m, n_zero", [(6, 1, 0), (8, 2, 0), (8, 2, 2), (10, 3, 3)])
@pytest.mark.parametrize("seed", [0, 1])
def test_smalbe_matches_enumeration(n, m, n_zero, seed):
    A, b, lb, B, c = be_problem(seed, n, m, n_zero=n_zero)
    res = smalbe(A, b, lb, B, c, eps=1e-10)
    assert res.converged, res.reason
    x_ref, mu_ref = enumerate_be(A, b, lb, B, c)
    scale = np.abs(x_ref).max()
    np.testing.assert_allclose(res.x, x_ref, rtol=0, atol=1e-7 * scale)
    np.testing.assert_allclose(res.mu, mu_ref, rtol=0, atol=1e-6 * (1 + np.abs(mu_ref).max()))
    nb = np.linalg.norm(b)
    assert np.linalg.norm(B @ res.x - c) <= 1e-10 * nb
    assert_kkt(A, b, lb, res.x, tol=1e-9 * nb, B=B, c=c, mu=res.mu)
    assert_counters(res)
    assert sum(res.inner_iterations) == res.iterations
    assert len(res.inner_iterations) == res.outer_iterations
    assert len(res.gradient_norms) == len(res.constraint_norms) == res.outer_iterations
    assert res.penalty >= 30.0


@pytest.mark.parametrize("n, m, n_zero", [(25, 4, 0), (40, 5, 4)])
def test_smalbe_matches_slsqp(n, m, n_zero):
    A, b, lb, B, c = be_problem(200 + n, n, m, n_zero=n_zero)
    res = smalbe(A, b, lb, B, c, eps=1e-10)
    assert res.converged, res.reason
    x_ref = slsqp(A, b, lb, B, c)
    np.testing.assert_allclose(res.x, x_ref, rtol=0, atol=1e-6 * np.abs(x_ref).max())
    nb = np.linalg.norm(b)
    assert_kkt(A, b, lb, res.x, tol=1e-9 * nb, B=B, c=c, mu=res.mu)
    assert_counters(res)
    assert sum(res.inner_iterations) == res.iterations
    assert len(res.inner_iterations) == res.outer_iterations
    f = lambda x: 0.5 * x @ A @ x - b @ x
    assert f(res.x) <= f(x_ref) + 1e-8 * abs(f(x_ref))


def test_smalbe_feti_like_setting():
    """(6.17)-like problem: A = P F P + rho Q, G with orthonormal rows, bounds on a subset."""
    rng = np.random.default_rng(42)
    n, m, n_I = 30, 3, 12
    F = spd(rng, n, lo=0.5, hi=5.0, n_zero=0)
    G = np.linalg.qr(rng.standard_normal((n, m)))[0].T          # orthonormal rows
    Q = G.T @ G
    P = np.eye(n) - Q
    A = P @ F @ P + np.linalg.norm(F, 2) * Q
    lam_t = np.concatenate([rng.uniform(0, 1, n_I), rng.standard_normal(n - n_I)])
    e = G @ lam_t                                               # feasible by construction
    d = rng.standard_normal(n) * 5
    b = P @ d
    lb = np.concatenate([np.zeros(n_I), np.full(n - n_I, -np.inf)])
    res = smalbe(A, b, lb, G, e, M=1.0, rho0=30.0, Gamma=1.0, eps=1e-9, norm_BE=1.0)
    assert res.converged, res.reason
    x_ref = slsqp(A, b, lb, G, e)
    np.testing.assert_allclose(res.x, x_ref, atol=1e-6 * np.abs(x_ref).max())
    assert_kkt(A, b, lb, res.x, tol=1e-8 * np.linalg.norm(b), B=G, c=e, mu=res.mu)
    # sparse BE and LinearOperator A give the same result
    opA = LinearOperator(A.shape, matvec=lambda v: A @ v, dtype=float)
    res2 = smalbe(opA, b, lb, sp.csr_matrix(G), e, eps=1e-9, norm_BE=1.0)
    np.testing.assert_allclose(res2.x, res.x, atol=1e-7 * np.abs(x_ref).max())


def test_smalbe_default_rule_section_6_4():
    A, b, lb, B, c = be_problem(3, 20, 2, n_zero=1)
    res = smalbe(A, b, lb, B, c)            # eps = 1e-5 (Section 6.4)
    assert res.converged, res.reason
    nb = np.linalg.norm(b)
    assert res.gradient_norms[-1] <= 1e-5 * nb and res.constraint_norms[-1] <= 1e-5 * nb
    assert np.linalg.norm(B @ res.x - c) <= 1e-5 * nb
    # the returned x, not only the solver's own norms: KKT recomputed, and the QP's solution (SLSQP)
    assert_kkt(A, b, lb, res.x, tol=10 * 1e-5 * nb, B=B, c=c, mu=res.mu)
    x_ref = slsqp(A, b, lb, B, c)
    assert np.abs(res.x - x_ref).max() <= 1e-3 * np.abs(x_ref).max()      # measured 5.9e-5 at eps 1e-5


def test_smalbe_penalty_update():
    # a loose inner precision (large M) with a small rho0 makes the Lagrangian increase test
    # of Figure 6.7 step 4 fail, so rho is multiplied by beta
    A, b, lb, B, c = be_problem(0, 15, 3)
    res = smalbe(A, b, lb, B, c, rho0=0.1, M=100.0, beta=10.0, eps=1e-8, max_outer=200)
    assert res.converged, res.reason
    assert res.penalty >= 0.1 * 10.0 ** 2
    np.testing.assert_allclose(np.log10(res.penalty / 0.1) % 1.0, 0.0, atol=1e-9)  # powers of beta
    x_ref = slsqp(A, b, lb, B, c)
    np.testing.assert_allclose(res.x, x_ref, atol=1e-6 * np.abs(x_ref).max())
    # with the default parameters of Section 6.4 the penalty stays at rho0 = 30 here
    res = smalbe(A, b, lb, B, c, eps=1e-8)
    assert res.converged and res.penalty == 30.0


def test_smalbe_nonconvergence():
    A, b, lb, B, c = be_problem(1, 20, 3)
    res = smalbe(A, b, lb, B, c, eps=1e-12, maxiter=3)
    assert not res.converged and "maxiter" in res.reason
    assert res.iterations <= 3 and sum(res.inner_iterations) == res.iterations
    assert len(res.inner_iterations) == res.outer_iterations
    res = smalbe(A, b, lb, B, c, eps=1e-12, max_outer=1)
    assert not res.converged and "max_outer" in res.reason
    assert res.outer_iterations == 1 and res.mu is not None


@pytest.mark.parametrize("kwargs, name", [
    ({"M": 0.0}, "M"),
    ({"rho0": -1.0}, "rho0"),
    ({"eta": 0.0}, "eta"),
    ({"beta": 1.0}, "beta"),
    ({"Gamma": 0.0}, "Gamma"),
    ({"eps": 0.0}, "eps"),
    ({"max_outer": 0}, "max_outer"),
    ({"c": np.zeros(3)}, "c"),
    ({"BE": np.ones((2, 5))}, "BE"),
])
def test_smalbe_bad_arguments(kwargs, name):
    args = {"A": np.eye(4), "b": np.ones(4), "lb": np.zeros(4), "BE": np.ones((2, 4))}
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        smalbe(**args)


# --------------------------------------------------------------------------- scale invariance
@pytest.mark.parametrize("ka, kb", [(0, 0), (-500, 480), (480, -500), (-330, -330), (330, 330), (7, -3)])
def test_mprgp_power_of_two_scaling_gives_the_same_iterates(ka: int, kb: int) -> None:
    """A -> 2^ka A, b -> 2^kb b (lb with x): the same steps and x scaled by 2^(kb-ka) exactly, across the
    double range (p^T A p ~ 2^(2kb-ka) overflowed or underflowed before the rescaling). ||A|| is given:
    LAPACK's eigensolver scales by non-powers of two outside its safe range."""
    A, b, lb = bound_problem(3, 30)
    norm_A = estimate_norm(A)[0]
    ref = mprgp(A, b, lb, rtol=1e-10, norm_A=norm_A)
    sA, sb = 2.0 ** ka, 2.0 ** kb
    res = mprgp(A * sA, b * sb, lb * (sb / sA), rtol=1e-10, norm_A=norm_A * sA)
    assert ref.converged and res.converged, res.reason
    assert (res.iterations, res.n_cg, res.n_expansion, res.n_proportioning) == \
        (ref.iterations, ref.n_cg, ref.n_expansion, ref.n_proportioning)
    np.testing.assert_array_equal(res.x, ref.x * (sb / sA))


@pytest.mark.parametrize("es, et", [(-150, 150), (150, -150), (100, 100), (-200, -100)])
def test_mprgp_and_smalbe_powers_of_ten_scaling(es: int, et: int) -> None:
    """A -> s A, b -> t b (s, t powers of ten, t/s up to 1e300): the same iteration counts and x -> (t/s) x to
    round-off; SMALBE with rho0 and M scaled like A (units of A / ||BE||^2 and A) and feas_tol like x (the
    default eps ||b|| of Section 6.4 compares ||BE x - c|| with a quantity in the units of b)."""
    s, t = 10.0 ** es, 10.0 ** et
    A, b, lb = bound_problem(5, 40)
    ref = mprgp(A, b, lb, rtol=1e-10)
    res = mprgp(A * s, b * t, lb * (t / s), rtol=1e-10)
    assert res.converged and abs(res.iterations - ref.iterations) <= 1, (res.iterations, ref.iterations)
    assert np.linalg.norm(res.x * (s / t) - ref.x) <= 1e-10 * np.linalg.norm(ref.x)
    A, b, lb, B, c = be_problem(5, 40, 3)
    feas_tol = 1e-8 * np.linalg.norm(b)
    ref = smalbe(A, b, lb, B, c, eps=1e-8, feas_tol=feas_tol)
    res = smalbe(A * s, b * t, lb * (t / s), B, c * (t / s), eps=1e-8, rho0=30.0 * s, M=s,
                 feas_tol=feas_tol * (t / s))
    assert ref.converged and res.converged, res.reason
    assert abs(res.iterations - ref.iterations) <= 1 and res.outer_iterations == ref.outer_iterations
    assert np.linalg.norm(res.x * (s / t) - ref.x) <= 1e-8 * np.linalg.norm(ref.x)
    assert np.linalg.norm(res.mu / t - ref.mu) <= 1e-6 * np.linalg.norm(ref.mu)


@pytest.mark.parametrize("bound", [-np.inf, -0.05])
def test_mprgp_confirms_convergence_with_the_recomputed_gradient(bound):
    """cond 1e10, rtol 1e-9: the recursively updated gradient met the rule while ||g^P|| of the returned x,
    recomputed, was 100-1e6 times the threshold, and MPRGP said converged (a review); PCG says "tolerance
    not attained" on the same system, and so must MPRGP. At rtol 1e-6 both converge, and then the
    recomputed gradient meets the rule within the factor."""
    rng = np.random.default_rng(19)
    n = 40
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = (Q * np.geomspace(1, 1e10, n)) @ Q.T
    A = (A + A.T) / 2
    b = rng.standard_normal(n)
    lb = np.full(n, bound)

    def projected_gradient_norm(x):
        g = A @ x - b
        return float(np.linalg.norm(np.where(x > lb, g, np.minimum(g, 0.0))))

    tight = mprgp(A, b, lb, rtol=1e-9, maxiter=20000)
    assert not tight.converged and tight.reason.startswith("tolerance not attained")
    assert projected_gradient_norm(tight.x) > 10 * 1e-9 * np.linalg.norm(b)
    loose = mprgp(A, b, lb, rtol=1e-6, maxiter=20000)
    assert loose.converged, loose.reason
    assert projected_gradient_norm(loose.x) <= 10 * 1e-6 * np.linalg.norm(b)
    assert loose.gradient_norms.size == loose.iterations + 1


def test_qp_refuses_non_finite_matrices():
    """A NaN in A or BE reached LAPACK in the norm estimate: "Eigenvalues did not converge" (a review)."""
    A, b, lb = np.diag([2.0, 3.0, 4.0]), np.ones(3), np.zeros(3)
    bad = A.copy()
    bad[0, 1] = np.nan
    for call, field in [(lambda: mprgp(bad, b, lb), "A"), (lambda: mprgp(sp.csr_matrix(bad), b, lb), "A"),
                        (lambda: smalbe(A, b, lb, np.full((1, 3), np.inf), np.ones(1)), "BE")]:
        with pytest.raises(InputError, match=f"^{field}: has non-finite entries"):
            call()
    nan_operator = LinearOperator((3, 3), matvec=lambda v: np.full(3, np.nan), dtype=float)
    with pytest.raises(InputError, match="^A: the operator returned non-finite values"):
        mprgp(nan_operator, b, lb)


def test_mprgp_operator_turning_non_finite_is_a_breakdown_with_a_finite_x():
    rng = np.random.default_rng(4)
    n = 30
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = (Q * np.geomspace(1, 1e3, n)) @ Q.T
    calls = [0]

    def matvec(v):
        calls[0] += 1
        return A @ v if calls[0] <= 5 else np.full(n, np.nan)

    lb = np.full(n, -np.inf)
    lb[:5] = 0.0
    res = mprgp(LinearOperator((n, n), matvec=matvec, dtype=float), np.ones(n), lb, norm_A=1e3, rtol=1e-12)
    assert not res.converged and res.reason.startswith("breakdown: A returned non-finite values")
    assert np.all(np.isfinite(res.x)) and np.all(res.x >= lb)


def test_qp_zero_thresholds_are_refused():
    A, b, lb = np.diag([2.0, 3.0]), np.ones(2), np.zeros(2)
    with pytest.raises(InputError, match="^rtol: rtol and atol are both 0"):
        mprgp(A, b, lb, rtol=0.0)
    with pytest.raises(InputError, match="^atol: b = 0 makes the stopping rule"):
        smalbe(A, np.zeros(2), lb, np.ones((1, 2)), np.ones(1))
    res = smalbe(A, np.zeros(2), lb, np.ones((1, 2)), np.ones(1), atol=1e-10)
    assert res.converged and "<= atol = 1.000e-10" in res.reason
    np.testing.assert_allclose(res.x, [0.6, 0.4], atol=1e-8)      # min x^T A x / 2 on x1 + x2 = 1


def test_smalbe_takes_a_tiny_nonzero_b():
    """eps ||b|| underflowed to 0 for b ~ 1e-319 and the b = 0 refusal fired (a review)."""
    res = smalbe(np.diag([2.0, 3.0]), np.full(2, 1e-319), 0.0, np.ones((1, 2)), np.array([1e-319]))
    assert res.converged
    np.testing.assert_allclose(res.x / 1e-319, [0.6, 0.4], rtol=1e-2)


def test_norm_estimate_names_the_operator():
    bad = LinearOperator((3, 3), matvec=lambda v: np.full(3, np.inf), dtype=float)
    with pytest.raises(FloatingPointError):
        estimate_norm(bad)
    with pytest.raises(InputError, match="^BE: the operator returned non-finite values"):
        smalbe(np.diag([2.0, 3.0, 4.0]), np.ones(3), 0.0, LinearOperator((1, 3), matvec=lambda v: np.full(1, np.nan),
                                                                        rmatvec=lambda w: np.full(3, np.nan),
                                                                        dtype=float), np.ones(1))
    with pytest.raises(InputError, match="^tol: must be positive"):
        mprgp(np.diag([2.0, 3.0]), np.ones(2), 0.0, tol=0.0)
