"""Edge-average primal constraints (change of basis, ddsolve.dd.edges) for FETI-DP and BDDC."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ddsolve import prepare
from ddsolve.api import build_scene
from ddsolve.dd import Substructures
from ddsolve.dd.bddc import InterfaceMap, solve_bddc
from ddsolve.dd.direct import solve_direct
from ddsolve.dd.dual import dual_operators
from ddsolve.dd.fetidp import solve_fetidp
from ddsolve.dd.operators import DirichletSchur, PrimalConstrainedSolver
from ddsolve.scene import assemble
from ddsolve.spec import ProblemSpec

SOLVERS = {"fetidp": solve_fetidp, "bddc": solve_bddc}


def _local(ns, m, rho=1.0):
    return assemble(build_scene(ProblemSpec.from_mapping(dict(subdomains=ns, elements=m, rho=rho, f="random:1"))))


def _rings(rho=(1.0, 10.0, 0.1)):
    """Outer ring (Dirichlet), a middle ring and a centre square on a 12 x 12 grid: floating
    subdomains with one neighbour each, no cross point, closed edges; rho jumps."""
    scene = build_scene(ProblemSpec.from_mapping(dict(subdomains=3, elements=4, f="random:1")))
    c = np.abs(scene.coords[scene.elements].mean(axis=1) - 0.5).max(axis=1)
    labels = np.where(c > 0.3, 0, np.where(c > 0.15, 1, 2))
    return assemble(dataclasses.replace(scene, element_subdomain=labels.astype(np.int64),
                                        subdomain_body=np.zeros(3, dtype=np.int64), rho=np.asarray(rho),
                                        subdomain_grid=None))


def _energy_error(sub, u):
    ref = solve_direct(sub).u
    A = sub.global_matrix()
    e = u - ref
    return np.sqrt(e @ A @ e) / np.sqrt(ref @ A @ ref)


# ------------------------------------------------------------------ layout
def test_n_primal_counted_by_hand():
    # 2 x 2 subdomains: 1 interior cross point; 4 edges (the halves of the two interior lines)
    assert Substructures(_local(2, 3), primal="vertices").n_primal == 1
    assert Substructures(_local(2, 3), primal="vertices+edges").n_primal == 1 + 4
    # 3 x 3 subdomains: 4 interior cross points; 2 interior lines each way, 3 edges on each: 12
    sub = Substructures(_local(3, 4), primal="vertices+edges")
    assert sub.n_primal == 4 + 12
    assert sub.edges.n_edges == 12
    # every edge of a 3 x 3 subdomain grid with 4 x 4 elements each has 3 interior nodes, 2 copies
    counts = np.bincount(sub.edges.label[sub.edges.label >= 0])
    np.testing.assert_array_equal(counts, np.full(12, 3 * 2))
    assert solve_fetidp(sub, rtol=1e-10).extra["n_primal"] == 16
    assert solve_bddc(sub, rtol=1e-10).extra["n_primal"] == 16


def test_change_of_basis_is_consistent():
    sub = Substructures(_local(3, 4, "checkerboard:100"), primal="vertices+edges")
    space = sub.primal_space()
    hat, T = space.sub, space.T_W.toarray()
    # the transformed templates assemble to T^T K_W T (one basis for all copies of an edge)
    np.testing.assert_allclose(hat.K_W.toarray(), T.T @ sub.K_W.toarray() @ T, atol=1e-12)
    np.testing.assert_allclose(hat.f_W, T.T @ sub.f_W, atol=1e-14)
    # the representative's new variable is the edge average: u^ = e_rep gives u = 1 on its edge
    rep = np.flatnonzero(sub.edges.representative)[0]
    u = T[:, rep]
    on_edge = (sub.edges.label == sub.edges.label[rep]) & (sub.sub_of_W == sub.sub_of_W[rep])
    np.testing.assert_array_equal(u, on_edge.astype(float))
    # translates with the same edges still share one transformed template: 4 corner, 4 side and
    # 1 inner subdomain kinds, for any number of subdomains per side >= 3
    assert len(Substructures(_local(5, 4), primal="vertices+edges").primal_space().sub.stiffness) == 9
    # the original substructures are unchanged (other methods, direct solve, checks)
    assert not sub.vertex[sub.edges.representative].any()
    assert hat.vertex[sub.edges.representative].all()


def test_unknown_primal_kind_is_rejected():
    with pytest.raises(ValueError, match="primal"):
        Substructures(_local(2, 2), primal="edges")


# ------------------------------------------------------- against direct solves
@pytest.mark.parametrize("method", sorted(SOLVERS))
@pytest.mark.parametrize("templates", [True, False])
@pytest.mark.parametrize("ns,m,rho", [(3, 4, 1.0), (4, 3, "checkerboard:100"), (3, 5, "checkerboard:0.001")])
def test_structured_matches_direct(method, templates, ns, m, rho):
    sub = Substructures(_local(ns, m, rho), templates=templates, primal="vertices+edges")
    out = SOLVERS[method](sub, rtol=1e-10)
    assert out.krylov.converged
    assert _energy_error(sub, out.u) < 1e-8


@pytest.mark.parametrize("method", sorted(SOLVERS))
@pytest.mark.parametrize("geometry", ["lshape", "hole"])
def test_unstructured_metis_matches_direct(method, geometry):
    prep = prepare(ProblemSpec(method=method, mesh="unstructured", geometry=geometry, maxh=0.1, parts=6,
                               rho="checkerboard:10", primal="vertices+edges"))
    sub = prep.sub
    assert sub.edges.n_edges > 0
    out = SOLVERS[method](sub, rtol=1e-10)
    assert out.krylov.converged
    assert out.extra["n_primal"] == sub.n_primal > int(np.unique(sub.l2g[sub.vertex]).size)
    assert _energy_error(sub, out.u) < 1e-8


@pytest.mark.parametrize("method", sorted(SOLVERS))
@pytest.mark.parametrize("templates", [True, False])
def test_irregular_rho_jumps_match_direct(method, templates):
    sub = Substructures(_rings(), templates=templates, primal="vertices+edges")
    assert sub.floating_sub.any() and not sub.cross_point.any()
    out = SOLVERS[method](sub, rtol=1e-10)
    assert out.krylov.converged
    assert _energy_error(sub, out.u) < 1e-8


# ---------------------------------------------------------- exact spectra
def _dense(apply, n):
    return np.column_stack([apply(e) for e in np.eye(n)])


def exact_cond(sub, method):
    """cond(M^{-1} A) from the dense preconditioned operator of a small case (the solvers' operators)."""
    hat = sub.primal_space().sub
    cache: dict = {}
    schur = DirichletSchur(hat, hat.interface, cache)
    primal = PrimalConstrainedSolver(hat, hat.vertex, cache)
    if method == "bddc":
        im = InterfaceMap(hat, hat.interface)
        A = _dense(lambda u: im.gather(schur.matvec(im.scatter(u))), im.n)
        M = _dense(lambda r: im.gather(primal.solve(im.scatter(r, im.delta)), im.delta), im.n)
    else:
        B, B_D = hat.jump_operators(hat.interface & ~hat.vertex)
        F, Mf = dual_operators(B, B_D, primal.solve, schur.matvec)
        A, M = _dense(F, B.shape[0]), _dense(Mf, B.shape[0])
    ev = np.sort(np.linalg.eigvals(M @ A).real)
    ev = ev[ev > 1e-10 * ev[-1]]        # FETI-DP: the redundant multipliers' null space
    return ev[-1] / ev[0]


@pytest.mark.parametrize("method", sorted(SOLVERS))
def test_edges_lower_the_condition_number(method):
    # 3 x 3 subdomains, rho = 1, H/h = 4, 8, 16; the exact spectra (FETI-DP and BDDC agree, up to
    # the eigenvalues 0 and 1) measured: vertices 1.8806, 2.4786, 3.1965; vertices+edges 1.1013,
    # 1.2439, 1.4319
    hh = (4, 8, 16)
    cond = {p: np.array([exact_cond(Substructures(_local(3, m), primal=p), method) for m in hh])
            for p in ("vertices", "vertices+edges")}
    vert, edge = cond["vertices"], cond["vertices+edges"]
    np.testing.assert_allclose(vert, [1.8806, 2.4786, 3.1965], rtol=1e-4)
    np.testing.assert_allclose(edge, [1.1013, 1.2439, 1.4319], rtol=1e-4)
    assert np.all(edge < 0.6 * vert)
    # milder growth in H/h: from H/h = 4 to 16 the edges add 0.33, the vertices alone 1.32
    assert edge[-1] - edge[0] < 0.3 * (vert[-1] - vert[0])
    assert edge[-1] / edge[0] < 1.35 < 1.65 < vert[-1] / vert[0]


# ------------------------------------------------------------------ refusals
@pytest.mark.parametrize("problem,method", [("poisson", "feti"), ("poisson", "direct"), ("multibody", "feti-feti"),
                                            ("multibody", "hybrid"), ("contact", "active-set"),
                                            ("contact", "smalbe")])
def test_other_methods_refuse_edges(problem, method):
    from ddsolve.errors import InputError
    with pytest.raises(InputError) as info:
        ProblemSpec.from_mapping(dict(problem=problem, method=method, primal="vertices+edges"))
    assert info.value.field == "primal" and "fetidp and bddc only" in str(info.value)
    for ok in ("fetidp", "bddc"):
        assert ProblemSpec.from_mapping(dict(method=ok, primal="Vertices+Edges")).primal == "vertices+edges"


def test_mpiexec_refuses_edges():
    pytest.importorskip("mpi4py")
    from ddsolve.errors import InputError
    from ddsolve.parallel.run import check_supported
    with pytest.raises(InputError) as info:
        check_supported(ProblemSpec(method="bddc", subdomains=4, primal="vertices+edges"), 2)
    assert info.value.field == "primal"


@pytest.mark.parametrize("weighted", [False, True])
def test_one_product_of_all_blocks_equals_the_per_template_loop(weighted):
    """PrimalSpace with every subdomain its own template: the transformed blocks of one block-diagonal
    triple product equal those of the per-subdomain loop (structured layouts), bit for bit."""
    from ddsolve.dd import edges as edges_module

    prep = prepare(ProblemSpec(method="bddc", mesh="unstructured", geometry="hole", maxh=0.08, parts=9,
                               rho="checkerboard:10", primal="vertices+edges"))
    sub = Substructures(prep.sub.local, templates=False, primal="vertices+edges")
    if weighted:                                  # weighted edge averages (as DDInverse at order >= 2)
        sub.edge_weights = 1.0 + np.random.default_rng(2).random(sub.scene.n_nodes)
    space = sub.primal_space()
    ed = sub.edges
    e = np.flatnonzero((ed.label >= 0) & ~ed.representative)
    assert e.size > 0 and (ed.coef is not None) == weighted
    cf = None if ed.coef is None else ed.coef[e]
    par = ed.parent_entry[e] if cf is None else np.where(cf != 0, ed.anchor_entry[e], e)
    args = (sub.sub_of_W[e], sub.local_index[e], sub.local_index[ed.rep_entry[e]], sub.local_index[par], cf)
    template, loop = edges_module._transformed_templates(sub, *args)
    np.testing.assert_array_equal(template, np.arange(sub.n_sub))
    assert len(space.sub.stiffness) == len(loop) == sub.n_sub
    for a, b in zip(space.sub.stiffness, loop):
        assert a.shape == b.shape and (a != b).nnz == 0
