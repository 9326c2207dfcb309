"""FETI, FETI-DP and BDDC against the direct solve, spectra, scalability and robustness."""
import numpy as np
import pytest
import scipy.linalg as la

from ddsolve import ProblemSpec, solve
from ddsolve.dd.operators import DirichletSchur, PrimalConstrainedSolver

from conftest import dense, substructures

METHODS = ["feti", "fetidp", "bddc"]
CASES = [  # (subdomains, elements, rho): 2x2 has no floating subdomain, 3x3 and 4x4 have floating ones
    (2, 4, 1.0),
    (3, 4, "checkerboard:100"),
    (4, 6, 1.0),
    (4, 4, "checkerboard:0.001"),
]


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("ns,m,rho", CASES)
def test_matches_direct_solution(method, ns, m, rho):
    res = solve(ProblemSpec(method=method, subdomains=ns, elements=m, rho=rho, f="random:1",
                            rtol=1e-10, check=True))
    assert res.converged, res.reason
    assert res.error_vs_direct < 1e-7
    direct = solve(ProblemSpec(method="direct", subdomains=ns, elements=m, rho=rho, f="random:1"))
    np.testing.assert_allclose(res.u, direct.u, rtol=0, atol=1e-7 * np.abs(direct.u).max())


def test_direct_reference_is_exact_on_manufactured_solution():
    """solve_direct (the reference of every method test) on f = A u*: the load A u* of each dof is put on
    its subdomain copies weighted by delta, so that R^T f_W = A u* exactly as the solver assembles it."""
    from ddsolve.dd import solve_direct

    sub = substructures(subdomains=3, elements=4, rho="checkerboard:100")
    A = sub.global_matrix()
    u_star = np.random.default_rng(5).standard_normal(sub.ndof)
    sub.f_W = sub.delta * (A @ u_star)[sub.l2g]
    np.testing.assert_allclose(sub.assemble_vector(sub.f_W), A @ u_star, rtol=1e-14, atol=1e-14)
    out = solve_direct(sub)
    assert out.krylov is None and out.n_factorizations == 1
    np.testing.assert_allclose(out.u, u_star, rtol=0, atol=1e-10 * np.abs(u_star).max())


def test_fetidp_lanczos_matches_exact_spectrum():
    sub = substructures(subdomains=3, elements=4, f="random:2")
    cache: dict = {}
    dual = sub.interface & ~sub.vertex
    B, B_D = sub.jump_operators(dual)
    At = PrimalConstrainedSolver(sub, sub.vertex, cache)
    schur = DirichletSchur(sub, sub.interface, cache)
    n = B.shape[0]
    F = dense(lambda x: B @ At.solve(B.T @ x), n)
    M = dense(lambda x: B_D @ schur.matvec(B_D.T @ x), n)
    np.testing.assert_allclose(F, F.T, atol=1e-12)
    ev = la.eigh(F, la.inv(M), eigvals_only=True)
    res = solve(ProblemSpec(method="fetidp", subdomains=3, elements=4, f="random:2", rtol=1e-12, cond=True))
    assert res.lambda_max == pytest.approx(ev.max(), rel=1e-6)
    # lambda_min = 1 is a multiple eigenvalue at the bottom of the spectrum; the smallest
    # Ritz value approaches it from above more slowly than the isolated top one.
    assert res.lambda_min == pytest.approx(ev.min(), rel=1e-3)
    assert res.lambda_min >= ev.min() - 1e-10
    assert ev.min() >= 1 - 1e-10                                           # lambda_min(M^{-1} F) >= 1


@pytest.mark.parametrize("ns,m,rho", [(4, 8, 1.0), (3, 6, "checkerboard:100"), (5, 4, 1.0)])
def test_fetidp_and_bddc_have_the_same_spectrum(ns, m, rho):
    conds = {}
    for method in ("fetidp", "bddc"):
        res = solve(ProblemSpec(method=method, subdomains=ns, elements=m, rho=rho, f="random:0",
                                rtol=1e-10, cond=True))
        conds[method] = res.cond
    assert conds["fetidp"] == pytest.approx(conds["bddc"], rel=2e-3)     # measured <= 4.4e-4 apart (both Lanczos estimates of one spectrum)


def _cond(method, ns, m, **kw):
    res = solve(ProblemSpec(method=method, subdomains=ns, elements=m, f="random:0", rtol=1e-8, cond=True, **kw))
    assert res.converged
    return res.cond, res.iterations


@pytest.mark.parametrize("method", METHODS)
def test_condition_bounded_in_number_of_subdomains(method):
    conds = [_cond(method, ns, 4)[0] for ns in (2, 4, 8)]
    assert max(conds) < 4.0
    assert conds[2] < 1.25 * conds[1]


@pytest.mark.parametrize("method", ["fetidp", "bddc"])
def test_condition_grows_like_log_squared(method):
    hs = np.array([4, 8, 16, 32])
    conds = np.array([_cond(method, 3, m)[0] for m in hs])
    assert np.all(np.diff(conds) > 0)
    # least-squares fit cond = C1 + C2 (1 + log(H/h))^2 (the law of Figure 4.3) explains the data ...
    x = (1 + np.log(hs)) ** 2
    (C2, C1), *_ = np.linalg.lstsq(np.column_stack([x, np.ones_like(x)]), conds, rcond=None)
    assert C2 > 0
    assert np.max(np.abs(conds - (C1 + C2 * x)) / conds) < 0.05
    # ... and growth is far below linear in H/h
    assert conds[-1] / conds[0] < 0.5 * hs[-1] / hs[0]


@pytest.mark.parametrize("method", METHODS)
def test_rho_scaling_is_robust_to_jumps(method):
    _, it_one = _cond(method, 4, 4)
    for jump in ("checkerboard:1e4", "checkerboard:1e-4"):
        _, it = _cond(method, 4, 4, rho=jump)
        assert it <= 1.5 * it_one


def test_multiplicity_scaling_fails_for_jumps():
    cond_rho, it_rho = _cond("fetidp", 4, 4, rho="checkerboard:1e4")
    cond_mult, it_mult = _cond("fetidp", 4, 4, rho="checkerboard:1e4", scaling="multiplicity")
    assert cond_rho < 1.1                       # rho-scaling: jumps make the problem easier
    assert cond_mult > 10 * cond_rho            # multiplicity scaling: condition number blows up
    assert it_mult > 3 * it_rho


def test_non_convergence_is_a_result():
    res = solve(ProblemSpec(method="fetidp", subdomains=4, elements=8, f="random:0", rtol=1e-12, maxiter=2))
    assert not res.converged
    assert "maxiter" in res.reason
    assert res.iterations == 2 and len(res.residuals) == 3


@pytest.mark.parametrize("method", METHODS)
def test_factorizations_shared_across_identical_subdomains(method):
    counts = [solve(ProblemSpec(method=method, subdomains=ns, elements=4)).n_factorizations for ns in (4, 8)]
    # 9 Dirichlet/floating patterns (corner, edge, interior) + interior solver + coarse problem,
    # independent of the number of subdomains (one coefficient: no final error check, ddsolve.dd.check)
    assert counts[0] == counts[1] <= 11


def test_cond_only_when_asked():
    res = solve(ProblemSpec(method="bddc", subdomains=2, elements=4))
    assert res.cond is None and res.lambda_min is None and res.error_vs_direct is None
