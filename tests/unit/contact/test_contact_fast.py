"""Fast paths of the contact solve: explicit local Schur complements, interface-restricted
primal-constrained solves and inexact (adaptive) face solves, checked against the implicit
operators and the direct reference."""
from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from ddsolve.contact import ContactProblem
from ddsolve.contact.active_set import ActiveSetHybrid
from ddsolve.contact.direct import solve_contact_direct
from ddsolve.dd import Substructures
from ddsolve.dd.operators import DirichletSchur
from ddsolve.multibody.hybrid import HybridSolver
from ddsolve.scene import assemble
from ddsolve.scene.contact import two_membranes


def contact_problem(N: int, m: int) -> ContactProblem:
    return ContactProblem(Substructures(assemble(two_membranes(N, m))))


@pytest.fixture(scope="module")
def hybrid():
    p = contact_problem(4, 6)
    with threadpool_limits(1, "blas"):
        yield p, HybridSolver(p.sub, p.gi)


def test_explicit_schur_complement_equals_implicit(hybrid):
    p, h = hybrid
    rng = np.random.default_rng(1)
    w = rng.standard_normal(p.sub.n_W)
    implicit = DirichletSchur(p.sub, h.schur.gamma, h.factorization_cache, explicit=False)
    explicit = DirichletSchur(p.sub, h.schur.gamma, h.factorization_cache, explicit=True)
    assert explicit.explicit and not implicit.explicit
    a, b = implicit.matvec(w), explicit.matvec(w)
    assert np.abs(a - b).max() < 1e-12 * np.abs(a).max()
    assert np.all(b[~h.schur.gamma] == 0.0)
    # the hybrid's own S (auto) is explicit at this size
    assert h.schur.explicit


@pytest.mark.parametrize("which", ["body_solver", "local_interface_solver"])
def test_interface_restricted_primal_solve_equals_full_solve(hybrid, which):
    p, h = hybrid
    solver = getattr(h, which)
    rng = np.random.default_rng(2)
    mask = h.schur.gamma
    b = np.where(mask & (solver.r | solver.primal), rng.standard_normal(p.sub.n_W), 0.0)
    full = solver.solve(b)
    fast = solver.solve_interface(b, mask)
    ref = np.where(mask, full, 0.0)
    assert np.abs(fast - ref).max() < 1e-11 * np.abs(ref).max()


@pytest.mark.parametrize("explicit", [True, False])
def test_bddc_part_of_the_preconditioner_on_the_interface_space(hybrid, explicit):
    """M_BDDC of (4.11) through space_solve equals R_D^T A~^{-1} R_D on full W vectors."""
    p, h = hybrid
    mask = h.schur.gamma
    r = np.random.default_rng(5).standard_normal(h.gamma_space.n)
    ref = h.gamma_space.gather(h.body_solver.solve(h.gamma_space.scatter(r, h.delta_gamma)), h.delta_gamma)
    op = h.body_solver.interface(mask, explicit=explicit).space_operator(h.gamma_space, h.delta_gamma)
    got = op.apply(r)
    if explicit == h.body_solver.interface(mask).explicit:      # the operator M_BDDC uses
        assert np.array_equal(h.M_bddc(r), got)
    assert np.abs(got - ref).max() < 1e-11 * np.abs(ref).max()


def test_inexact_body_schur_complement_matches_interior_formula(hybrid):
    """S~_OL through interface operators equals A_GG - A_GI A~_II^{-1} A_IG with (4.9)-(4.10)."""
    p, h = hybrid
    v = np.random.default_rng(3).standard_normal(h.global_space.n)
    w = h.global_space.scatter(v)
    t = p.sub.K_W @ w
    x = h.inexact_interior_solve(t)
    ref = h.global_space.gather(p.sub.K_W @ (w - x))
    got = h.S_ol(v)
    assert np.abs(got - ref).max() < 1e-11 * np.abs(ref).max()


@pytest.mark.parametrize("explicit", [True, False, "switch"])
def test_active_set_with_and_without_explicit_operators_matches_direct(monkeypatch, count_factorizations, explicit):
    """Explicit blocks from the start, never (no block may be formed), or after the implicit applications
    have cost their setup (the rent-or-buy switch): the same solution, no factorization after the setup."""
    p = contact_problem(4, 8)
    ref = solve_contact_direct(p)
    import ddsolve.dd.operators as ops
    if explicit == "switch":
        monkeypatch.setattr(ops, "EXPLICIT_SETUP_MATVECS", -1)     # not at first use, but the blocks fit
    elif explicit:
        monkeypatch.setattr(ops, "EXPLICIT_SETUP_MATVECS", 10**9)
    else:
        monkeypatch.setattr(ops, "EXPLICIT_MAX_BLOCK", 0)          # no block fits: implicit throughout
    with threadpool_limits(1, "blas"):
        s = ActiveSetHybrid(p)
        assert s.hybrid.schur.explicit is (explicit is True)
        made = count_factorizations()
        sol = s.solve(rtol=1e-5)
    assert s.hybrid.schur.explicit is bool(explicit)
    if explicit == "switch":     # the body solver's interface solves switched too
        assert s.hybrid.schur._implicit_applications > 0
        assert any(i.explicit and i.applications > 0 for i in s.hybrid.body_solver._interfaces.values())
    assert made == []                                     # no factorization after the setup
    assert sol.converged, sol.reason
    assert np.array_equal(sol.active, ref.active)
    assert p.kkt(sol.u, sol.lam).max < 1e-5
    assert np.linalg.norm(sol.u - ref.u) < 1e-4 * np.linalg.norm(ref.u)
    assert np.linalg.norm(sol.lam - ref.lam) < 1e-3 * np.linalg.norm(ref.lam)


def test_explicit_interior_solution_equals_sparse(hybrid):
    p, h = hybrid
    rng = np.random.default_rng(4)
    w = np.where(h.schur.gamma, rng.standard_normal(p.sub.n_W), 0.0)
    implicit = DirichletSchur(p.sub, h.schur.gamma, h.factorization_cache, explicit=False)
    explicit = DirichletSchur(p.sub, h.schur.gamma, h.factorization_cache, explicit=True)
    assert explicit.explicit and explicit.extensions is not None
    for f in (p.sub.f_W, rng.standard_normal(p.sub.n_W)):
        a = implicit.interior_solution(f, w)
        b = explicit.interior_solution(f, w)
        assert np.abs(a - b).max() < 1e-11 * np.abs(a).max()
        a = implicit.harmonic_extension_rhs(f)
        b = explicit.harmonic_extension_rhs(f)
        assert np.abs(a - b).max() < 1e-11 * np.abs(a).max()
    f = rng.standard_normal(p.sub.n_W)
    explicit.interior_solution(f, w)
    f[:] = rng.standard_normal(p.sub.n_W)              # changed in place: the cached A_II^{-1} f_I is stale
    assert np.abs(explicit.interior_solution(f, w) - implicit.interior_solution(f, w)).max() < 1e-10


@pytest.mark.parametrize("N, m, forcing", [(4, 8, 3e-3), (8, 4, 1e-2), (8, 8, 3e-3)])
def test_inexact_face_solves_match_direct_and_end_at_rtol(N, m, forcing):
    p = contact_problem(N, m)
    ref = solve_contact_direct(p)
    with threadpool_limits(1, "blas"):
        s = ActiveSetHybrid(p)
        exact = s.solve(rtol=1e-5)
        sol = s.solve(rtol=1e-5, forcing=forcing)
    assert sol.converged, sol.reason
    assert np.array_equal(sol.active, ref.active)
    assert p.kkt(sol.u, sol.lam).max < 1e-5
    assert np.linalg.norm(sol.u - ref.u) < 1e-4 * np.linalg.norm(ref.u)
    assert np.linalg.norm(sol.lam - ref.lam) < 1e-3 * np.linalg.norm(ref.lam)
    tols = sol.extra["face_rtol"]
    assert len(tols) == sol.outer_iterations and tols[-1] == 1e-5 and tols[0] == forcing
    # one extra (loose) face solve when the initial active set is already right
    assert sol.total_iterations <= exact.total_iterations + 5
    # forcing at or below rtol is the exact method
    same = s.solve(rtol=1e-5, forcing=1e-5)
    assert same.inner_iterations == exact.inner_iterations


def test_interface_blocks_are_formed_only_where_they_pay_off(hybrid):
    """Many small subdomains (N = 4, H/h = 6): explicit blocks; two large ones per membrane
    (N = 2, H/h = 24): forming (A_rr^{-1})_DD would cost more solves than 16 implicit
    applications, so space_solve / solve_interface use the implicit solve, with the same result."""
    p, h = hybrid
    assert h.body_solver.interface(h.schur.gamma).explicit
    big = contact_problem(2, 24)
    with threadpool_limits(1, "blas"):
        hb = HybridSolver(big.sub, big.gi)
        mask = hb.schur.gamma
        assert not hb.body_solver.interface(mask).explicit and not hb.schur.explicit
        rng = np.random.default_rng(4)
        b = np.where(mask & (hb.body_solver.r | hb.body_solver.primal), rng.standard_normal(big.sub.n_W), 0.0)
        implicit = hb.body_solver.solve_interface(b, mask)
        explicit = hb.body_solver.solve_interface(b, mask, explicit=True)     # force the dense blocks
        assert np.abs(explicit - implicit).max() < 1e-11 * np.abs(implicit).max()
        sol = ActiveSetHybrid(big).solve(rtol=1e-8)
    direct = solve_contact_direct(big)
    assert sol.converged and np.array_equal(sol.active, direct.active)
    assert np.linalg.norm(sol.u - direct.u) < 1e-6 * np.linalg.norm(direct.u)


def test_active_set_seconds_count_the_solver_built_in_the_call(monkeypatch):
    """seconds = the whole call (setup included), extra["setup_seconds"] = the part spent building the
    solver: their difference is the solve phase of the JSON (it used to subtract a setup done outside)."""
    import time

    from ddsolve.contact import active_set as module

    problem = contact_problem(2, 4)
    real_init = module.ActiveSetHybrid.__init__

    def slow_init(self, *args, **kwargs):
        real_init(self, *args, **kwargs)
        time.sleep(0.5)                       # a setup long enough to be seen above the solve's noise

    monkeypatch.setattr(module.ActiveSetHybrid, "__init__", slow_init)
    t0 = time.perf_counter()
    sol = module.solve_contact_active_set(problem, rtol=1e-8, pcg_rtol=1e-8)
    wall = time.perf_counter() - t0
    assert sol.converged and 0.5 <= sol.extra["setup_seconds"] <= sol.seconds <= wall
    assert wall - sol.seconds < 0.25          # the 0.5 s setup is inside (slack for a loaded machine)
    built = ActiveSetHybrid(problem)                                   # its setup outside the call
    reused = module.solve_contact_active_set(problem, rtol=1e-8, pcg_rtol=1e-8, solver=built)
    assert reused.extra["setup_seconds"] == 0.0
    assert np.array_equal(reused.u, sol.u)
