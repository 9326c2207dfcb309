"""SMALBE/MPRGP on the FETI-DP dual of the two-membrane problem (3.1) (Section 6.4, (6.13)-(6.17)).

References: the primal-dual active set method with sparse direct solves
(:func:`solve_contact_direct`, KKT residuals ~1e-14) and Table 6.1 of the thesis
(N_dof(lambda)).

Accuracy expectations (see the module docstring of ``ddsolve.contact.smalbe_dual``):
the stopping rule ||g^P|| <= eps ||b||, ||G lambda|| <= eps min(||b||, ||e||) bounds displacement
jumps and gaps, and the contact force error by eps times the net load on Omega^2 (the
contact extremes of the stress study, below); the relative primal force residual (KKT
stationarity) is K times the jumps,
about 3-8 eps on these grids. So stationarity < 1e-5 needs eps = 1e-6..1e-7, not the
thesis's 1e-5; at eps = 1e-10 it is ~5e-10 (< 1e-8).
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from ddsolve.contact.direct import ContactSolution, solve_contact_direct
from ddsolve.contact.problem import ContactProblem
from ddsolve.contact.smalbe_dual import DEFAULT_RHO_BAR, FORCE_FACTOR, solve_contact_smalbe
from ddsolve.dd import Substructures
from ddsolve.multibody.fetifeti import FetiFetiSolver
from ddsolve.scene import assemble
from ddsolve.scene.contact import two_membranes

GRIDS = [(2, 4), (4, 4), (2, 8)]
_CACHE: dict = {}


def setup(N: int, m: int, f=None):
    """(problem, FETI-FETI solver, direct reference), cached per grid."""
    key = (N, m, None if f is None else "custom")
    if key not in _CACHE:
        p = ContactProblem(Substructures(assemble(two_membranes(N, m, f=f))))
        ref = solve_contact_direct(p)
        assert ref.converged and p.kkt(ref.u, ref.lam).max < 1e-11
        _CACHE[key] = (p, FetiFetiSolver(p.sub, p.gi), ref)
    return _CACHE[key]


def run(N: int, m: int, eps: float, **kw) -> tuple[ContactProblem, ContactSolution, ContactSolution]:
    """SMALBE itself (``polish=False`` unless given: the tests of its accuracy must not see the
    FETI-FETI refinement of the default ``polish="auto"``)."""
    p, ff, ref = setup(N, m)
    kw.setdefault("polish", False)
    return p, solve_contact_smalbe(p, eps=eps, solver=ff, **kw), ref


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ------------------------------------------------------------------ sizes (Table 6.1)
@pytest.mark.parametrize("N,m,thesis", [(4, 4, 161), (4, 8, 369), (8, 4, 705)])
def test_nlambda_equals_table_6_1(N, m, thesis):
    """N_dof(lambda) of Table 6.1 = local FETI-DP multipliers + N m + 1 contact pairs."""
    p = ContactProblem(Substructures(assemble(two_membranes(N, m))))
    s = solve_contact_smalbe(p)
    assert s.converged, s.reason
    assert s.extra["nlambda"] == thesis
    assert s.extra["n_contact"] == p.n_contact == N * m + 1
    assert s.extra["n_local"] == thesis - (N * m + 1)


# ------------------------------------------------------------------ KKT conditions (5.5)
@pytest.mark.parametrize("N,m", GRIDS)
def test_kkt_thesis_tolerance(N, m):
    eps = 1e-5
    p, s, _ = run(N, m, eps)
    assert s.converged, s.reason
    k = p.kkt(s.u, s.lam)
    assert k.dual_feasibility == 0.0 and np.all(s.lam >= 0.0)
    assert k.feasibility < eps
    assert k.complementarity < 0.1 * eps
    # stationarity is 3-8 eps here (force residual = K x jumps; module docstring); < 1e-5 is
    # not attained at eps = 1e-5
    assert k.stationarity < 10 * eps


@pytest.mark.parametrize("N,m", GRIDS)
@pytest.mark.parametrize("eps,bound", [(1e-7, 1e-5), (1e-10, 1e-8)])
def test_kkt_tight_tolerance(N, m, eps, bound):
    p, s, _ = run(N, m, eps)
    assert s.converged, s.reason
    k = p.kkt(s.u, s.lam)
    assert k.max < bound, k
    assert k.stationarity < 10 * eps


def test_kkt_stationarity_scales_with_eps():
    """The primal residual of SMALBE itself follows the dual tolerance (not capped above 1e-10)."""
    stat = []
    for eps in (1e-6, 1e-9):
        p, s, _ = run(4, 4, eps, polish=False)
        stat.append(p.kkt(s.u, s.lam).stationarity)
    assert stat[1] < 1e-2 * stat[0]


# ------------------------------------------------------------------ agreement with the direct reference
@pytest.mark.parametrize("N,m", GRIDS)
@pytest.mark.parametrize("eps", [1e-5, 1e-10])
def test_agrees_with_direct(N, m, eps):
    p, s, ref = run(N, m, eps)
    assert s.converged, s.reason
    e_ref = p.energy(ref.u)
    assert abs(p.energy(s.u) - e_ref) <= eps * abs(e_ref)
    assert rel(s.u, ref.u) <= 5 * eps
    assert rel(s.lam, ref.lam) <= 50 * eps
    # active sets may differ only where the exact multiplier is below what eps resolves; on these
    # grids they agree exactly (smallest positive reference multiplier ~ 1.6 % of the largest)
    tiny = np.maximum(s.lam, ref.lam) <= 100 * eps * ref.lam.max()
    assert np.all((s.active == ref.active) | tiny)
    if eps <= 1e-5:
        assert np.array_equal(s.active, ref.active)


def test_agrees_with_direct_other_load():
    """A seeded random load instead of the Dostal patches (partial contact: 6 of 9 pairs)."""
    scene = two_membranes(2, 4)
    c = scene.coords[scene.elements].mean(axis=1)
    f = np.random.default_rng(7).uniform(-1.0, 0.5, c.shape[0]) - 4.0 * ((c[:, 0] < 1) & (c[:, 1] > 0.6))
    p, ff, ref = setup(2, 4, f=f)
    assert 0 < ref.active.sum() < p.n_contact
    s = solve_contact_smalbe(p, eps=1e-10, solver=ff)
    assert s.converged, s.reason
    assert p.kkt(s.u, s.lam).max < 1e-8
    assert rel(s.u, ref.u) < 1e-9 and rel(s.lam, ref.lam) < 1e-8
    assert np.array_equal(s.active, ref.active)


# ------------------------------------------------------------------ dual data (6.14)-(6.17)
def test_homogenization_and_equilibrium():
    """lambda~_I = -e~/n_c with e~ = int_{Omega^2} f = -0.25; the contact forces carry that load."""
    eps = 1e-5
    p, s, _ = run(2, 4, eps)
    assert s.extra["lambda_tilde"] == pytest.approx(0.25 / p.n_contact, rel=1e-12)
    assert s.extra["net_load"] == pytest.approx(0.25, rel=1e-12)
    assert s.extra["norm_e"] == pytest.approx(0.25 / np.sqrt(p.n_contact), rel=1e-12)
    # sum of the balanced multiplier is exact; zeroing the inactive entries moves it by kappa each
    lam_bal = s.extra["lambda"][s.extra["n_local"]:]
    assert lam_bal.sum() == pytest.approx(0.25, rel=1e-12)
    assert abs(s.lam.sum() - 0.25) <= abs(s.extra["equality_defect"]) * np.sqrt(p.n_contact)
    # stopping rule: ||G lambda|| <= eps min(||b||, ||e||), so the force error is <= eps
    assert s.extra["tol_equality"] == pytest.approx(eps * min(s.extra["norm_b"], s.extra["norm_e"]))
    assert abs(s.extra["equality_defect"]) <= s.extra["tol_equality"]
    assert s.extra["force_error"] == pytest.approx(abs(s.lam.sum() - 0.25) / 0.25)
    assert s.extra["force_error"] <= eps


def test_norm_estimate_and_steplength():
    """||P F P|| (checked against a dense eigensolve), rho_bar = 1 (default) or ||P F P|| (None),
    and alpha = 1.9 / (||P F P + rho_bar Q|| + rho) in (0, 2/||Hessian||]."""
    p, ff, _ = setup(2, 4)
    B_gl, _ = p.gi.operators(None)
    B = sp.vstack([ff.B_loc, B_gl]).tocsr()
    n = B.shape[0]
    F = np.column_stack([B @ ff.primal_solver.solve(B.T @ e) for e in np.eye(n)])
    G = np.asarray(B @ ff.R.toarray()).ravel()
    G /= np.linalg.norm(G)
    P = np.eye(n) - np.outer(G, G)
    norm_pfp = np.linalg.eigvalsh(P @ F @ P).max()
    for rho_bar, want in ((DEFAULT_RHO_BAR, 1.0), (None, norm_pfp)):
        s = solve_contact_smalbe(p, solver=ff, rho_bar=rho_bar)
        assert s.converged, s.reason
        assert s.extra["norm_PFP"] == pytest.approx(norm_pfp, rel=1e-8)
        assert s.extra["rho_bar"] == pytest.approx(want, rel=1e-8)
        norm_a = max(norm_pfp, s.extra["rho_bar"])
        hess = max(norm_pfp, s.extra["rho_bar"] + s.extra["penalty"])
        assert 0 < s.extra["alpha"] <= 2.0 / hess
        assert s.extra["alpha"] == pytest.approx(1.9 / (norm_a + s.extra["penalty"]), rel=2e-3)


# ------------------------------------------------------------------ counters, reuse, failure
@pytest.mark.parametrize("N,m", GRIDS)
def test_iteration_counters(N, m):
    _, s, _ = run(N, m, 1e-5)
    x = s.extra
    assert s.outer_iterations == len(s.inner_iterations) >= 1
    assert s.total_iterations == sum(s.inner_iterations)
    assert x["n_cg"] + x["n_expansion"] + x["n_proportioning"] == s.total_iterations
    # every MPRGP step multiplies by the Hessian at least once; one F per Hessian product
    assert x["n_hessian"] >= s.total_iterations
    assert x["n_Fmult"] >= x["n_hessian"]
    assert len(x["gradient_norms"]) == s.outer_iterations
    assert x["constraint_norms"][-1] <= 1e-5 * x["norm_b"]


#: Recorded baseline of OUR code at N = m = 4, eps = 1e-5, M = 1, rho0 = 30, Gamma = 1, no polish
#: (outer iterations, MPRGP steps): default rules [10, 6, 6, 2]; the thesis preset's rules
#: (rho_bar = ||P F P||, ||G lambda|| <= eps ||b||) [14, 4, 3, 4, 3]. Table 6.1 reports 4 / 41.
BASELINE_4_4 = {"default": (4, 24), "thesis": (5, 28)}


@pytest.mark.parametrize("preset", ["default", "thesis"])
def test_stopping_rule_reached_and_counts_near_baseline(preset):
    """SMALBE's own properties at N = m = 4: its stopping rule holds at the returned iterate, the
    KKT conditions hold to the accuracy the rule implies, and the counts stay within 25 % (outer:
    +-1) of the recorded baseline of this code (a regression band, not a comparison with the thesis)."""
    from ddsolve.presets import solver_options

    eps = 1e-5
    options = {**solver_options(preset, "contact", "smalbe"), "polish": False}
    p, s, ref = run(4, 4, eps, **options)
    x = s.extra
    assert s.converged, s.reason
    assert x["gradient_norms"][-1] <= eps * x["norm_b"]
    tol_eq = x["tol_equality"] if x["tol_equality"] is not None else eps * x["norm_b"]
    assert abs(x["equality_defect"]) <= tol_eq and x["constraint_norms"][-1] <= tol_eq
    k = p.kkt(s.u, s.lam)
    assert k.dual_feasibility == 0.0 and k.feasibility < eps and k.complementarity < 0.1 * eps
    assert k.stationarity < (20 if preset == "default" else 10) * eps      # measured 4e-6 / 6.4e-5
    assert np.array_equal(s.active, ref.active)
    outer, total = BASELINE_4_4[preset]
    assert abs(s.outer_iterations - outer) <= 1
    assert 0.75 * total <= s.total_iterations <= 1.25 * total
    assert s.inner_iterations[0] == max(s.inner_iterations)     # the first outer iteration is the costliest


def test_solver_reuse_gives_identical_result():
    p, ff, _ = setup(2, 4)
    a = solve_contact_smalbe(p, solver=ff)
    b = solve_contact_smalbe(p)
    assert a.n_factorizations == 0 and b.n_factorizations > 0
    np.testing.assert_array_equal(a.u, b.u)
    np.testing.assert_array_equal(a.lam, b.lam)
    assert a.inner_iterations == b.inner_iterations


def test_nonconvergence_is_reported_not_raised():
    p, s, _ = run(4, 4, 1e-10, maxiter=5)
    assert not s.converged
    assert "maxiter" in s.reason
    assert s.total_iterations == 5
    assert s.u.shape == (p.ndof,) and s.lam.shape == (p.n_contact,)
    assert np.all(s.lam >= 0.0)


def test_invalid_parameters_are_reported():
    p, s, _ = run(2, 4, 1e-5, rho0=-1.0)
    assert not s.converged and "rho0" in s.reason
    p, s, _ = run(2, 4, 1e-5, rho_bar=0.0)
    assert not s.converged and "rho_bar" in s.reason


@pytest.mark.parametrize("N, m", [(4, 4), (8, 8)])
def test_polish_on_the_active_set_reaches_the_active_set_accuracy(N, m):
    """polish=True: FETI-FETI on SMALBE's active set brings stationarity from 2e-5..4e-5 to below 1e-6."""
    p, plain, ref = run(N, m, 1e-5, polish=False)
    _, sol, _ = run(N, m, 1e-5, polish=True)
    assert sol.converged and sol.extra["polish"] == "accepted" and sol.extra["polish_iterations"] > 0
    assert sol.inner_iterations == plain.inner_iterations           # the SMALBE part is unchanged
    assert p.kkt(plain.u, plain.lam).stationarity > 1e-5             # why the polish exists
    assert p.kkt(sol.u, sol.lam).max < 1e-6
    assert np.array_equal(sol.active, ref.active)
    assert np.linalg.norm(sol.u - ref.u) < 1e-7 * np.linalg.norm(ref.u)


# ------------------------------------------------------------------ contact extremes (stress study)
def extreme(load: str, N: int, m: int):
    """(problem, direct reference) for a named load of :func:`ddstudies.stress.contact_load`."""
    from ddstudies.stress import contact_load

    key = (N, m, load)
    if key not in _CACHE:
        p = ContactProblem(Substructures(assemble(two_membranes(N, m, f=contact_load(load, N, m)))))
        _CACHE[key] = (p, solve_contact_direct(p))
    return _CACHE[key]


def agrees(p, s, ref, eps):
    """The stress study's rule: u and lambda within 100 eps of direct, same active set."""
    return (rel(s.u, ref.u) <= 100 * eps and rel(s.lam, ref.lam) <= 100 * eps
            and np.array_equal(s.active, ref.active))


@pytest.mark.parametrize("load,N,m", [("single-node", 4, 4), ("single-node", 8, 8), ("barely:1e-8", 4, 4),
                                      ("barely:1e-4", 4, 4)])
def test_small_contact_force_is_resolved_by_the_stopping_rule(load, N, m):
    """||G lambda|| <= eps ||e||: a one-node zone or a tiny net load is resolved by SMALBE itself."""
    eps = 1e-5
    p, ref = extreme(load, N, m)
    s = solve_contact_smalbe(p, eps=eps, polish=False)
    assert s.converged, s.reason
    assert "polish" not in s.extra
    assert abs(s.extra["equality_defect"]) <= eps * s.extra["norm_e"] < eps * s.extra["norm_b"]
    assert s.extra["force_error"] <= eps
    assert agrees(p, s, ref, eps)


def test_thesis_rule_alone_leaves_the_force_unresolved():
    """The defect the rule fixes: with rho_bar = ||P F P|| SMALBE meets Section 6.4's rule on the
    one-node zone long before the contact force; without the rescue that is converged=False."""
    eps = 1e-5
    p, ref = extreme("single-node", 8, 8)
    s = solve_contact_smalbe(p, eps=eps, rho_bar=None, polish=False)
    assert not s.converged
    assert "Section 6.4" in s.reason and "not resolved" in s.reason and "\n" not in s.reason
    assert abs(s.extra["equality_defect"]) <= eps * s.extra["norm_b"]
    assert s.extra["force_error"] > 10 * eps
    # the rescue: FETI-FETI on SMALBE's (right) active set
    r = solve_contact_smalbe(p, eps=eps, rho_bar=None)
    assert r.converged and r.extra["polish"] == "accepted", r.reason
    assert "rescued" in r.reason
    assert r.inner_iterations == s.inner_iterations
    assert r.extra["force_error"] <= eps
    assert agrees(p, r, ref, eps)


def test_barely_pressed_body_is_rescued_or_fails_cleanly():
    """Net load 1e-8 against a self-balanced load O(1): G lambda cannot reach eps ||e|| (~1e-14);
    the rescue on SMALBE's active set gives the direct solution (N = m = 8, the stress case)."""
    eps = 1e-5
    p, ref = extreme("barely:1e-8", 8, 8)
    plain = solve_contact_smalbe(p, eps=eps, polish=False)
    assert not plain.converged and "not resolved" in plain.reason
    assert np.all(np.isfinite(plain.u)) and np.all(plain.lam >= 0)
    s = solve_contact_smalbe(p, eps=eps)
    assert s.converged and s.extra["polish"] == "accepted", s.reason
    assert abs(s.lam.sum() - 1e-8) <= 10 * eps * 1e-8
    assert agrees(p, s, ref, eps)


def test_rescue_rejected_on_a_wrong_active_set(monkeypatch):
    """A rescue whose active set is wrong (negative multiplier) is rejected: converged=False."""
    import ddsolve.contact.smalbe_dual as sd

    eps = 1e-5
    p, ref = extreme("single-node", 8, 8)
    real = sd._polish

    def wrong_set(problem, solver, active, *args, **kw):        # add a pair the load lifts off
        bad = active.copy()
        bad[0] = True
        return real(problem, solver, bad, *args, **kw)

    monkeypatch.setattr(sd, "_polish", wrong_set)
    s = solve_contact_smalbe(p, eps=eps, rho_bar=None)
    assert not s.converged and s.extra["polish"] == "rejected"
    assert "polish on the active set rejected" in s.reason and "\n" not in s.reason


def test_acceptance_check():
    """Force balance of the floating body and finite values; converged results always pass it."""
    from ddsolve.contact.smalbe_dual import _accept

    p, s, ref = run(4, 4, 1e-5)
    net = s.extra["net_load"]
    assert s.extra["force_error"] <= 1e-5 <= FORCE_FACTOR * 1e-5
    assert _accept(p, ref.u, ref.lam, net, 1e-5, {})[0]
    ok, why = _accept(p, ref.u, 1.01 * ref.lam, net, 1e-5, {})
    assert not ok and "net load" in why
    ok, why = _accept(p, np.full_like(ref.u, np.nan), ref.lam, net, 1e-5, {})
    assert not ok and "non-finite" in why


def test_invalid_polish_is_reported():
    p, ff, _ = setup(2, 4)
    s = solve_contact_smalbe(p, solver=ff, polish="always")
    assert not s.converged and "polish" in s.reason


@pytest.mark.parametrize("N, m", [(4, 4), (8, 8)])
def test_default_refines_on_the_active_set(N, m):
    """polish="auto" (default): SMALBE's iterations unchanged, the refined pair is returned."""
    p, plain, ref = run(N, m, 1e-5)
    _, sol, _ = run(N, m, 1e-5, polish="auto")
    assert sol.converged and sol.extra["polish"] == "accepted", sol.reason
    assert sol.inner_iterations == plain.inner_iterations
    assert p.kkt(sol.u, sol.lam).max < min(1e-6, p.kkt(plain.u, plain.lam).max)
    assert np.array_equal(sol.active, ref.active)


@pytest.mark.parametrize("rho, rejected", [("body-checkerboard:1e-6", True), ("body-checkerboard:1e6", True),
                                          ("checkerboard:1e4", False)])
def test_coefficient_jumps_are_refined_or_rejected(rho, rejected):
    """With jumps SMALBE's dual rule (relative to ||b||) leaves large force residuals or a lambda
    off by 1%; polish="auto" refines on the active set (kept only if the KKT residual drops),
    and without it a pair whose stationarity exceeds STATIONARITY_FACTOR eps is not converged."""
    from ddsolve.api import build_scene
    from ddsolve.contact.direct import solve_contact_direct
    from ddsolve.contact.smalbe_dual import STATIONARITY_FACTOR
    from ddsolve.dd import Substructures
    from ddsolve.scene import assemble
    from ddsolve.spec import ProblemSpec

    eps = 1e-5
    spec = ProblemSpec.from_mapping({"problem": "contact", "method": "smalbe", "subdomains": 8, "elements": 8,
                                     "rho": rho})
    p = ContactProblem(Substructures(assemble(build_scene(spec)), scaling=spec.scaling, gamma=spec.gamma))
    ref = solve_contact_direct(p)
    s = solve_contact_smalbe(p, eps=eps)
    assert s.converged and s.extra["polish"] == "accepted", s.reason
    assert np.array_equal(s.active, ref.active)
    assert rel(s.lam, ref.lam) < 1e-5 and p.kkt(s.u, s.lam).stationarity < 10 * eps
    plain = solve_contact_smalbe(p, eps=eps, polish=False)
    stationarity = p.kkt(plain.u, plain.lam).stationarity
    if rejected:
        assert stationarity > STATIONARITY_FACTOR * eps
        assert not plain.converged and "KKT stationarity" in plain.reason
    else:   # checkerboard 1e4: SMALBE alone leaves lambda off by ~1e-2 at a stationarity of ~2 eps, which no
        # residual check tells from the Table 6.1 runs; the equality solve on its active set, run as a check
        # without the polish, moves lambda by as much (it was reported converged before)
        assert stationarity <= STATIONARITY_FACTOR * eps
        assert rel(plain.lam, ref.lam) > 1e-3
        assert not plain.converged and "moves lambda by" in plain.reason
        assert plain.extra["verify_lambda_change"] > 1e-3
