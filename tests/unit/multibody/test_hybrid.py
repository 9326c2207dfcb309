"""Hybrid method (Section 4.2 of Lee 2009) against the direct multibody solve."""
from functools import lru_cache

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from ddsolve.dd import Substructures
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.direct import solve_constrained_direct
from ddsolve.multibody.hybrid import HybridSolver
from ddsolve.scene import assemble, structured_square

CASES = ["full", "middle"]


@lru_cache(maxsize=None)
def problem(nb: int, ns: int, m: int, random: bool = True):
    """(sub, gi, solver) of problem (4.32) with seeded element-wise loads in [-1, 1]."""
    scene = structured_square(nb, ns, m, f=1.0)
    if random:
        f = np.random.default_rng(0).uniform(-1, 1, scene.elements.shape[0])
        scene = structured_square(nb, ns, m, f=f)
    sub = Substructures(assemble(scene))
    gi = GlobalInterface(sub)
    with threadpool_limits(1, "blas"):
        hs = HybridSolver(sub, gi)
    return sub, gi, hs


def rel_error(u, ref):
    return np.abs(u - ref).max() / np.abs(ref).max()


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("nb,ns,m,n_float", [(2, 2, 4, 0), (3, 2, 4, 1), (4, 2, 2, 4)])
def test_matches_direct_solution(nb, ns, m, n_float, case):
    sub, gi, _ = problem(nb, ns, m)
    hs = HybridSolver(sub, gi)            # fresh solver: the first solve reports its factorizations
    assert hs.floating.size == n_float
    active = gi.contact_mask(case)
    with threadpool_limits(1, "blas"):
        res = hs.solve(active, rtol=1e-10)
    ref = solve_constrained_direct(sub, gi, active).u
    assert res.krylov.converged, res.krylov.reason
    assert res.u.shape == (sub.ndof,)
    assert rel_error(res.u, ref) < 1e-8
    # energy norm of the error, relative
    A = sub.global_matrix()
    e = res.u - ref
    assert np.sqrt(e @ (A @ e)) <= 1e-8 * np.sqrt(ref @ (A @ ref))
    assert res.nlambda == active.sum() == res.extra["lambda"].shape[0]
    assert res.n_factorizations > 0
    # the recovered u_Gamma has no jump on the active pairs, and lambda balances S^ u - g^
    a = hs.active_set(active)
    u_g = res.extra["u_gamma"]
    scale = np.abs(u_g).max()
    assert np.abs(a.jump.matvec(u_g)).max() < 1e-8 * scale
    resid = hs.g_hat - hs.S_hat(u_g) - hs.jump_transpose(a, res.extra["lambda"])
    assert np.abs(resid).max() < 1e-7 * np.abs(hs.g_hat).max()


def test_new_active_set_reuses_factorizations_and_warm_start(count_factorizations):
    sub, gi, _ = problem(3, 2, 4)
    hs = HybridSolver(sub, gi)
    full, middle = gi.contact_mask("full"), gi.contact_mask("middle")
    with threadpool_limits(1, "blas"):
        first = hs.solve(middle, rtol=1e-8)
        assert first.n_factorizations == hs.n_factorizations > 0
        # count every factorization made from now on
        made = count_factorizations()
        second = hs.solve(full, rtol=1e-8)
        assert second.n_factorizations == 0 and made == []
        ref = solve_constrained_direct(sub, gi, full).u
        assert rel_error(second.u, ref) < 1e-6
        # warm start on the same mask from the converged state: no more iterations
        again = hs.solve(full, rtol=1e-8, x0=second.extra["state"])
        assert again.krylov.iterations <= second.krylov.iterations
        assert again.krylov.iterations <= 2
        assert rel_error(again.u, ref) < 1e-6
        # warm start from another active set (lambda kept where still active) is still exact
        # (its residual starts with a tiny displacement block: PCR is restarted if the
        # recursive residual drifts from the true one)
        switched = hs.solve(full, rtol=1e-10, x0=first.extra["state"])
        assert switched.krylov.converged, switched.krylov.reason
        assert switched.krylov.true_residual <= 2e-10 * switched.krylov.residuals[0]
        assert rel_error(switched.u, ref) < 1e-7
        # a partially converged state helps
        rough = hs.solve(full, rtol=1e-3)
        cold = hs.solve(full, rtol=1e-8)
        warm = hs.solve(full, rtol=1e-8, x0=rough.extra["state"])
        assert warm.krylov.iterations <= cold.krylov.iterations
        assert made == []


def test_inexact_body_schur_complement():
    # m = 1: Gamma_0 is only the primal cross point, the BDDC step of (4.10) is exact,
    # so S~_OL equals the exact body Schur complement S_OL
    for m, exact in ((1, True), (2, False)):
        sub, gi, hs = problem(3, 2, m, random=False)
        n = hs.global_space.n
        S_t = np.column_stack([hs.S_ol(e) for e in np.eye(n)])
        A = sub.global_matrix().toarray()
        G = hs.global_space.dofs
        I = np.setdiff1d(np.arange(sub.ndof), G)
        S = A[np.ix_(G, G)] - A[np.ix_(G, I)] @ np.linalg.solve(A[np.ix_(I, I)], A[np.ix_(I, G)])
        np.testing.assert_allclose(S_t, S_t.T, atol=1e-13)
        if exact:
            np.testing.assert_allclose(S_t, S, atol=1e-12)
        else:
            assert np.abs(S_t - S).max() > 1e-6
            # A~_II^{-1} >= A_II^{-1} (BDDC eigenvalues >= 1) gives S~_OL <= S_OL
            assert np.linalg.eigvalsh(S - S_t).min() > -1e-12


def test_preconditioned_spectrum_small():
    """B^{-1} A on range(P_R) x (V^k cap range(Z B^)): indefinite, bounded, away from 0."""
    sub, gi, hs = problem(3, 2, 2)
    a = hs.active_set(gi.contact_mask("full"))
    ng, na = hs.n_gamma, a.n_active
    eye_g, eye_l = np.eye(ng), np.eye(na)
    S = np.column_stack([hs.S_hat(e) for e in eye_g])
    B = np.column_stack([hs.jump(a, e) for e in eye_g])
    P = np.column_stack([a.projection.apply(e) for e in eye_l])
    PR = np.column_stack([hs.P_R(e) for e in eye_g])
    MB = np.column_stack([hs.M_bddc(e) for e in eye_g])
    MD = np.column_stack([hs.M_D(a, e) for e in eye_l])
    np.testing.assert_allclose(S, S.T, atol=1e-12)
    np.testing.assert_allclose(MB, MB.T, atol=1e-12)
    np.testing.assert_allclose(MD, MD.T, atol=1e-12)
    # BDDC block: eigenvalues of M_BDDC S^ on range(P_R) in [1, C]
    QU = np.linalg.svd(PR)[0][:, :ng - hs.floating.size]
    ev_b = np.sort(np.linalg.eigvals(QU.T @ MB @ QU @ QU.T @ S @ QU).real)
    assert ev_b[0] > 1 - 1e-8 and ev_b[-1] < 3
    # lambda space: V^k cap range(Z B^) (redundant multipliers at cross points removed)
    U, sv, _ = np.linalg.svd(P @ B)
    QL = U[:, sv > 1e-10]
    Q = np.block([[QU, np.zeros((ng, QL.shape[1]))], [np.zeros((na, QU.shape[1])), QL]])
    Akkt = np.block([[S, (P @ B).T], [P @ B, np.zeros((na, na))]])
    M = np.block([[PR @ MB @ PR, np.zeros((ng, na))], [np.zeros((na, ng)), P @ MD @ P]])
    Mr = Q.T @ M @ Q
    assert np.linalg.eigvalsh(Mr).min() > 0
    ev = np.sort(np.linalg.eigvals(Mr @ (Q.T @ Akkt @ Q)).real)
    assert ev[0] < 0 < ev[-1]
    assert np.abs(ev).min() > 0.5 and np.abs(ev).max() < 4


def test_unsupported_floating_body_raises():
    _, gi, hs = problem(3, 2, 2)
    with pytest.raises(ValueError, match="floating"):
        hs.solve(np.zeros(gi.n_gl, dtype=bool))
    with pytest.raises(ValueError, match="shape"):
        hs.solve(np.ones(gi.n_gl + 1, dtype=bool))


def test_no_active_multipliers_without_floating_bodies():
    sub, gi, hs = problem(2, 2, 2)
    active = np.zeros(gi.n_gl, dtype=bool)
    res = hs.solve(active, rtol=1e-10)
    ref = solve_constrained_direct(sub, gi, active).u
    assert res.nlambda == 0 and rel_error(res.u, ref) < 1e-7


def iterations(nb, ns, m, case):
    _, gi, hs = problem(nb, ns, m)
    with threadpool_limits(1, "blas"):
        res = hs.solve(gi.contact_mask(case), rtol=1e-6)
    assert res.krylov.converged, res.krylov.reason
    return res.krylov.iterations


@pytest.mark.parametrize("case", CASES)
def test_iterations_bounded_in_number_of_bodies_and_subdomains(case):
    """Table 4.2 (first rows): counts stay bounded as N_b and N_s grow (||r_n|| / ||r_0|| < 1e-6)."""
    by_bodies = [iterations(nb, 2, 2, case) for nb in (2, 4)]
    by_subdomains = [iterations(2, ns, 2, case) for ns in (2, 4, 6)]
    counts = by_bodies + by_subdomains
    assert max(counts) <= 30, counts
    assert by_subdomains[-1] - by_subdomains[0] <= 10, by_subdomains


def test_operators_are_formed_in_setup(monkeypatch):
    """The constructor forms the operators (setup); a solve forms no dense block and no interface solve."""
    from ddsolve.dd import operators, primal

    sub, gi, _ = problem(3, 2, 4)
    with threadpool_limits(1, "blas"):
        hs = HybridSolver(sub, gi)
    assert hs.schur.explicit                                  # thesis-sized blocks: explicit at once
    assert hs._bddc_space_solve is not None and hs._local_space_solve is not None
    built = []
    for cls, name in ((operators.DirichletSchur, "_build_explicit"),
                      (primal.ExplicitInterfaceSolve, "_build_blocks"),
                      (primal.PrimalConstrainedSolver, "interface")):
        original = getattr(cls, name)
        monkeypatch.setattr(cls, name, lambda self, *a, _o=original, _n=name, **k: built.append(_n) or _o(self, *a, **k))
    with threadpool_limits(1, "blas"):
        out = hs.solve(gi.contact_mask("full"), rtol=1e-8)
    assert built == []
    ref = solve_constrained_direct(sub, gi, gi.contact_mask("full")).u
    assert rel_error(out.u, ref) < 1e-6
