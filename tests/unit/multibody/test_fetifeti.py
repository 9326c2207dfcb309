"""Multibody problem (4.32): global interface, FETI-FETI against the direct solve and Table 4.1."""
import numpy as np
import pytest
import scipy.linalg as la
import scipy.sparse as sp

import ddsolve.dd.local as local_mod
from ddsolve import ProblemSpec, solve
from ddsolve.dd import Substructures
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.direct import solve_constrained_direct
from ddsolve.multibody.fetifeti import FetiFetiSolver
from ddsolve.scene import assemble, structured_square

from conftest import dense


def build(nb, ns, m, seed=0):
    scene = structured_square(nb, ns, m)
    scene.f = np.random.default_rng(seed).uniform(-1, 1, scene.elements.shape[0])
    sub = Substructures(assemble(scene))
    return sub, GlobalInterface(sub)


def energy_error(sub, u, ref):
    A = sub.global_matrix()
    e = u - ref
    return np.sqrt(e @ (A @ e) / (ref @ (A @ ref)))


def test_global_interface_counts():
    sub, gi = build(2, 2, 2)
    # 4 faces with 3 free non-corner nodes + 6 fully redundant pairs at the centre cross point
    assert gi.n_gl == 4 * 3 + 6
    # middle third [1/3, 2/3] of a face of length 1/2 holds one node (y = 1/4) per face
    assert gi.contact_mask("middle").sum() == 4
    assert gi.floating_bodies().size == 0
    np.testing.assert_allclose(sub.scene.coords[gi.pair_nodes[:, 0]], sub.scene.coords[gi.pair_nodes[:, 1]])
    sub4, gi4 = build(4, 2, 2)
    assert gi4.floating_bodies().tolist() == [5, 6, 9, 10]


@pytest.mark.parametrize("contact", ["full", "middle"])
@pytest.mark.parametrize("nb,ns,m", [(2, 2, 3), (3, 2, 2), (4, 2, 2)])   # 0, 1 and 4 floating bodies
def test_fetifeti_matches_constrained_direct(nb, ns, m, contact):
    sub, gi = build(nb, ns, m)
    active = gi.contact_mask(contact)
    ref = solve_constrained_direct(sub, gi, active).u
    out = FetiFetiSolver(sub, gi).solve(active, rtol=1e-10)
    assert out.krylov.converged
    assert energy_error(sub, out.u, ref) < 1e-7
    # the solution is continuous on the active contact area
    dofs = sub.dof_of_node[gi.pair_nodes[active]]
    assert np.abs(out.u[dofs[:, 0]] - out.u[dofs[:, 1]]).max() < 1e-7 * np.abs(ref).max()


def _exact_cond(nb, ns, m):
    sub, gi = build(nb, ns, m)
    ff = FetiFetiSolver(sub, gi)
    B_gl, B_gl_D = gi.operators(gi.contact_mask("full"))
    B = sp.vstack([ff.B_loc, B_gl]).tocsr()
    B_D = sp.vstack([ff.B_loc_D, B_gl_D]).tocsr()
    n = B.shape[0]
    F = dense(lambda x: B @ ff.primal_solver.solve(B.T @ x), n)
    M = dense(lambda x: B_D @ ff._tilde_schur(B_D.T @ x), n)
    ev = np.real(la.eigvals(M @ F))
    ev = ev[ev > 1e-9]
    return ev.max() / ev.min(), ev.min()


@pytest.mark.parametrize("case,thesis", [((2, 4, 2), 7.1076), ((2, 2, 4), 4.5201), ((2, 6, 2), 12.0749)])
def test_exact_condition_equals_table_4_1(case, thesis):
    cond, lmin = _exact_cond(*case)
    assert lmin == pytest.approx(1.0, abs=1e-9)
    assert cond == pytest.approx(thesis, rel=1e-4)


@pytest.mark.parametrize("case,thesis", [((2, 4, 2), 7.1076), ((2, 2, 4), 4.5201)])
def test_lanczos_estimate_within_one_percent(case, thesis):
    nb, ns, m = case
    res = solve(ProblemSpec(problem="multibody", method="feti-feti", bodies=nb, subdomains=ns, elements=m,
                            cond=True))
    assert res.converged
    assert res.cond == pytest.approx(thesis, rel=0.01)


def test_changing_the_active_set_does_not_refactor(monkeypatch):
    sub, gi = build(4, 2, 2)
    ff = FetiFetiSolver(sub, gi)
    calls = []
    original = local_mod._Factor.__init__
    monkeypatch.setattr(local_mod._Factor, "__init__", lambda self, K: (calls.append(1), original(self, K))[1])
    for contact in ("middle", "full"):
        active = gi.contact_mask(contact)
        out = ff.solve(active, rtol=1e-10)
        assert energy_error(sub, out.u, solve_constrained_direct(sub, gi, active).u) < 1e-7
    assert calls == []


def test_cli_multibody_json(capsys):
    from ddsolve.cli import main
    import json
    assert main(["solve", "--problem", "multibody", "--bodies", "3", "--subdomains", "2", "--elements", "2",
                 "--method", "feti-feti", "--contact", "middle", "--check", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["converged"] and data["error_vs_direct"] < 1e-5 and data["n_floating_bodies"] == 1


@pytest.mark.parametrize("contact", ["full", "middle"])
def test_cli_hybrid_json(capsys, contact):
    from ddsolve.cli import main
    import json
    assert main(["solve", "--problem", "multibody", "--bodies", "3", "--subdomains", "2", "--elements", "2",
                 "--method", "hybrid", "--contact", contact, "--check", "--cond", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["converged"] and data["error_vs_direct"] < 1e-5
    assert data["cond"] is None            # PCR gives no Lanczos estimate
    assert data["nlambda"] == data["n_active"]
