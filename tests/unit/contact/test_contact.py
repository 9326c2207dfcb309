"""Model problem (3.1): scene, KKT residuals, the direct reference and the active set + hybrid method."""
from __future__ import annotations

import json

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from ddsolve import cli
from ddsolve.contact import ContactProblem
from ddsolve.contact.active_set import ActiveSetHybrid
from ddsolve.contact.direct import solve_contact_direct
from ddsolve.dd import Substructures
from ddsolve.errors import InputError
from ddsolve.scene import assemble
from ddsolve.scene.contact import dostal_loads, two_membranes


def contact_problem(N: int, m: int, **kw) -> ContactProblem:
    return ContactProblem(Substructures(assemble(two_membranes(N, m, **kw))))


@pytest.mark.parametrize("N, m, ndof, nlam", [(4, 4, 561, 17), (4, 8, 2145, 33), (8, 4, 2145, 33),
                                               (4, 12, 4753, 49), (12, 4, 4753, 49)])
def test_dof_counts_match_table_5_1(N, m, ndof, nlam):
    p = contact_problem(N, m)
    assert (p.ndof, p.n_contact) == (ndof, nlam)
    # pairs: Omega^1 copy first, ordered along Gamma_c = {1} x [0, 1]
    xy = p.sub.scene.coords[p.gi.pair_nodes]
    assert np.allclose(xy[:, 0], xy[:, 1]) and np.allclose(xy[:, :, 0], 1.0)
    assert np.all(np.diff(p.y) > 0) and p.y[0] == 0.0 and p.y[-1] == 1.0


def test_dostal_loads_and_their_integral():
    scene = two_membranes(4, 4)
    area = (1 / 16) ** 2
    body = scene.subdomain_body[scene.element_subdomain]
    # f = -3 on a quarter of Omega^1, -1 on a quarter of Omega^2
    assert scene.f[body == 0].sum() * area == pytest.approx(-0.75)
    assert scene.f[body == 1].sum() * area == pytest.approx(-0.25)
    c = np.array([[0.5, 0.8], [0.5, 0.7], [1.5, 0.1], [1.5, 0.3]])
    assert np.array_equal(dostal_loads(c), [-3.0, 0.0, -1.0, 0.0])


@pytest.mark.parametrize("f", [0.0, 1.0, np.r_[np.zeros(256), np.ones(256)]])
def test_load_that_does_not_press_the_floating_membrane_is_rejected(f):
    with pytest.raises(InputError, match="negative integral"):
        two_membranes(4, 4, f=f)


def test_kkt_residuals_detect_each_violation():
    p = contact_problem(2, 4)
    ref = solve_contact_direct(p)
    assert ref.converged
    ok = p.kkt(ref.u, ref.lam)
    assert ok.max < 1e-12
    bad = ref.lam.copy()
    bad[np.argmax(bad)] *= -1                       # negative pressure
    assert p.kkt(ref.u, bad).dual_feasibility > 0.5
    u = ref.u.copy()
    free = ~ref.active
    u[p.pair_dofs[free, 0]] += 1.0                  # Omega^1 above Omega^2 where not in contact
    k = p.kkt(u, ref.lam)
    assert k.feasibility > 0.1 and k.stationarity > 0.1


def test_direct_reference_against_brute_force_enumeration():
    """On a tiny grid the PDAS solution is the best of all active sets that satisfy (5.5)."""
    p = contact_problem(1, 4)                       # 5 contact pairs: 31 non-empty active sets
    ref = solve_contact_direct(p)
    from ddsolve.contact.direct import solve_face_direct
    best = None
    for code in range(1, 2 ** p.n_contact):
        act = np.array([(code >> k) & 1 for k in range(p.n_contact)], dtype=bool)
        u = solve_face_direct(p, act)
        lam = p.multipliers_from_residual(u, act)
        if np.all(lam >= -1e-12) and np.all(p.gap(u) <= 1e-12):
            e = p.energy(u)
            best = e if best is None else min(best, e)
    assert best is not None
    assert p.energy(ref.u) == pytest.approx(best, rel=1e-12)


@pytest.mark.parametrize("N, m", [(2, 4), (4, 4), (4, 8), (8, 4)])
def test_active_set_hybrid_matches_direct_and_satisfies_kkt(N, m):
    p = contact_problem(N, m)
    ref = solve_contact_direct(p)
    with threadpool_limits(1, "blas"):
        sol = ActiveSetHybrid(p).solve(rtol=1e-5)
    assert sol.converged, sol.reason
    k = p.kkt(sol.u, sol.lam)
    assert k.stationarity < 1e-5
    assert k.feasibility < 1e-4 and k.dual_feasibility < 1e-4 and k.complementarity < 1e-4
    assert np.array_equal(sol.active, ref.active)
    assert abs(p.energy(sol.u) - p.energy(ref.u)) < 1e-6 * abs(p.energy(ref.u))
    assert np.linalg.norm(sol.u - ref.u) < 1e-4 * np.linalg.norm(ref.u)
    assert np.linalg.norm(sol.lam - ref.lam) < 1e-3 * np.linalg.norm(ref.lam)
    assert sol.total_iterations == sum(sol.inner_iterations) and len(sol.inner_iterations) == sol.outer_iterations
    assert sol.pcg_iterations > 0


def test_active_set_hybrid_tight_tolerance():
    p = contact_problem(4, 4)
    ref = solve_contact_direct(p)
    with threadpool_limits(1, "blas"):
        sol = ActiveSetHybrid(p).solve(rtol=1e-11, pcg_rtol=1e-8)
    assert sol.converged, sol.reason
    assert p.kkt(sol.u, sol.lam).stationarity < 1e-8
    assert np.linalg.norm(sol.u - ref.u) < 1e-8 * np.linalg.norm(ref.u)
    assert np.linalg.norm(sol.lam - ref.lam) < 1e-7 * np.linalg.norm(ref.lam)


def test_initial_guess_is_the_metric_projection():
    """lambda^ = argmin (l - l*)^T M (l - l*) over l >= 0 (Figure 5.1), checked by its KKT conditions."""
    p = contact_problem(4, 4)
    with threadpool_limits(1, "blas"):
        s = ActiveSetHybrid(p)
        lam_star, lam_hat, kr, qp = s.initial_multipliers(1e-10)
        assert kr.converged and qp.converged
        n = p.n_contact
        Minv = np.column_stack([s.preconditioner(e) for e in np.eye(n)])   # tiny: 17 x 17
    assert np.allclose(Minv, Minv.T, atol=1e-12 * np.abs(Minv).max())
    grad = np.linalg.solve(Minv, lam_hat - lam_star)                    # M (l^ - l*) = mu >= 0
    assert np.all(lam_hat >= 0)
    scale = np.abs(grad).max()
    assert np.all(grad >= -1e-6 * scale)
    assert np.abs(grad * lam_hat).max() < 1e-6 * scale * lam_hat.max()
    # and it predicts the final active set well
    ref = solve_contact_direct(p)
    assert np.count_nonzero((lam_hat > 1e-4 * lam_hat.max()) != ref.active) <= 2


def test_outer_iterations_reuse_factorizations(count_factorizations):
    p = contact_problem(8, 4)                      # needs more than one outer iteration
    with threadpool_limits(1, "blas"):
        s = ActiveSetHybrid(p)
        made = count_factorizations()
        sol = s.solve(rtol=1e-5)
    assert sol.converged and sol.outer_iterations >= 2
    assert made == []


def test_cli_contact_json(capsys):
    code = cli.main(["solve", "--problem", "contact", "--subdomains", "2", "--elements", "4", "--check", "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("outer_iterations", "inner_iterations", "pcg_iterations", "total_iterations",
                "n_active", "energy", "kkt_residual"):
        assert key in out
    assert out["problem"] == "contact" and out["method"] == "active-set" and out["bodies"] == 2
    assert out["converged"] and out["kkt_residual"] < 1e-4 and out["error_vs_direct"] < 1e-4
    assert out["total_iterations"] == sum(out["inner_iterations"]) == out["iterations"]


@pytest.mark.parametrize("argv, field", [
    (["--bodies", "3"], "bodies"),
    (["--method", "fetidp"], "method"),
    (["--f", "1"], "f"),
    (["--f", "dostal:-3"], "f"),
])
def test_cli_contact_bad_input(capsys, argv, field):
    code = cli.main(["solve", "--problem", "contact", "--subdomains", "2", "--elements", "4", *argv])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"ddsolve: error: {field}:") and "\n" not in err


def test_literal_figure_6_3_update_frees_one_pair_per_outer_iteration():
    p = contact_problem(8, 4)
    ref = solve_contact_direct(p)
    with threadpool_limits(1, "blas"):
        s = ActiveSetHybrid(p)
        literal = s.solve(rtol=1e-5, removal="blocking")
        default = s.solve(rtol=1e-5)
    for sol in (literal, default):
        assert sol.converged, sol.reason
        assert np.array_equal(sol.active, ref.active)
    hist = literal.extra["active_history"]
    removed = [a - b for a, b in zip(hist, hist[1:]) if b < a]
    assert removed and max(removed) == 1
    assert default.outer_iterations <= literal.outer_iterations
    with pytest.raises(ValueError, match="removal"):
        s.solve(removal="some")
