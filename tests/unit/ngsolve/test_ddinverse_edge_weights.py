"""DDInverse edge averages at order >= 2: weighted by the integrals of the H1 shapes along the edges."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

ngs = pytest.importorskip("ngsolve")
from netgen.geom2d import unit_square

from ddsolve.ngsolve import DDInverse
from ddsolve.ngsolve.dofs import element_dofs, vertex_table
from ddsolve.ngsolve.local import interface_edge_weights, mesh_edge_numbers

_MESHES: dict[float, object] = {}


def square(maxh: float):
    if maxh not in _MESHES:
        _MESHES[maxh] = ngs.Mesh(unit_square.GenerateMesh(maxh=maxh))
    return _MESHES[maxh]


def poisson(order: int, maxh: float):
    fes = ngs.H1(square(maxh), order=order, dirichlet="left|bottom")
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += (1 + ngs.x * ngs.y) * ngs.grad(u) * ngs.grad(v) * ngs.dx
    a.Assemble()
    f = ngs.LinearForm(fes)
    f += (1 + ngs.x) * v * ngs.dx
    f.Assemble()
    return fes, a, f


@pytest.mark.parametrize("order", [2, 3, 4])
@pytest.mark.parametrize("method", ["bddc", "fetidp"])
def test_weighted_edges_match_direct(order, method):
    fes, a, f = poisson(order, 0.1)
    ref = ngs.GridFunction(fes)
    ref.vec.data = a.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky") * f.vec
    inv = DDInverse(a, method=method, parts=8, primal="vertices+edges", rtol=1e-10)
    assert inv.sub.edge_weights is not None and inv.sub.edges.coef is not None
    x = inv.solve(f.vec.FV().NumPy())
    r = ref.vec.FV().NumPy()
    assert inv.converged
    assert np.linalg.norm(x - r) / np.linalg.norm(r) < 1e-8


def test_order_one_keeps_the_nodal_average():
    _, a, _ = poisson(1, 0.1)
    inv = DDInverse(a, parts=8, primal="vertices+edges")
    assert inv.sub.edge_weights is None and inv.sub.edges.coef is None


@pytest.mark.parametrize("order", [2, 3])
def test_interface_weights_are_shape_integrals(order):
    # the hats: half the lengths of their interface mesh edges; the quadratic edge shape: -h/12;
    # the higher ones: 0 (NGSolve's edge shapes are orthogonal to the constants along the edge)
    mesh = square(0.2)
    fes = ngs.H1(mesh, order=order)
    V = vertex_table(mesh)
    part = (V.min(axis=1) % 3).astype(np.int64)
    w = interface_edge_weights(fes, part, V, element_dofs(fes))
    num = mesh_edge_numbers(mesh, V)
    np.testing.assert_array_equal(np.sort(num, axis=1), np.sort(mesh_edge_numbers(mesh, V, element_dofs(fes), order), axis=1))
    pts = np.array([v.point for v in mesh.vertices])
    hat = np.zeros(mesh.nv)
    shape = np.zeros((mesh.nedge, order - 1))
    on = np.zeros(mesh.nedge, dtype=bool)
    for e in mesh.edges:
        els = [el.nr for el in e.elements]
        if len(els) == 2 and part[els[0]] != part[els[1]]:
            on[e.nr] = True
            a, b = (v.nr for v in e.vertices)
            h = np.linalg.norm(pts[a] - pts[b])
            hat[[a, b]] += h / 2
            shape[e.nr] = [-h / 12] + [0.0] * (order - 2)
    assert on.sum() > 10
    np.testing.assert_allclose(w[:mesh.nv], hat, atol=1e-14)
    for e in np.flatnonzero(on):
        dofs = list(fes.GetDofNrs(ngs.NodeId(ngs.EDGE, int(e))))
        np.testing.assert_allclose(np.abs(w[dofs]), np.abs(shape[e]), atol=1e-14)


def _line_integral(gfu, mesh, segments, n_gauss=6):
    """int of gfu along the mesh edges ``segments`` (pairs of vertex points), Gauss-Legendre."""
    t, wq = np.polynomial.legendre.leggauss(n_gauss)
    t, wq = (t + 1) / 2, wq / 2
    total = 0.0
    for p, q in segments:
        h = np.linalg.norm(q - p)
        total += h * sum(wi * gfu(mesh(*(p + ti * (q - p)))) for ti, wi in zip(t, wq))
    return total


@pytest.mark.parametrize("order", [2, 3, 4])
def test_primal_unknown_is_the_mean_along_the_edge(order):
    fes, a, f = poisson(order, 0.12)
    mesh = fes.mesh
    inv = DDInverse(a, parts=6, primal="vertices+edges", rtol=1e-12)
    u = inv.solve(f.vec.FV().NumPy())
    sub, edges = inv.sub, inv.sub.edges
    h1_of_W = inv.h1_of_gdof[sub.l2g]
    u_hat = spla.spsolve(inv.space.T_W.tocsc(), u[h1_of_W])       # the new variables of the solution
    pts = np.array([v.point for v in mesh.vertices])
    edge_dofs = {e.nr: set(fes.GetDofNrs(ngs.NodeId(ngs.EDGE, e.nr))) for e in mesh.edges}
    edge_verts = {e.nr: [v.nr for v in e.vertices] for e in mesh.edges}
    checked = 0
    for rep in np.flatnonzero(edges.representative):
        on = np.flatnonzero(edges.rep_entry == rep)
        dofs = set(h1_of_W[on].tolist())
        segments = [(pts[edge_verts[e][0]], pts[edge_verts[e][1]]) for e, d in edge_dofs.items()
                    if d and d <= dofs]
        assert segments
        # u with its coefficients off the edge zeroed: int_E of it is sum_j w_j u_j (the end
        # vertices of E are primal, not in the average); the indicator of E's dofs gives sum_j w_j
        mean_part = ngs.GridFunction(fes)
        ones = ngs.GridFunction(fes)
        idx = np.fromiter(dofs, dtype=np.int64)
        mean_part.vec.FV().NumPy()[idx] = u[idx]
        ones.vec.FV().NumPy()[idx] = 1.0
        mean = _line_integral(mean_part, mesh, segments) / _line_integral(ones, mesh, segments)
        assert u_hat[rep] == pytest.approx(mean, rel=1e-9, abs=1e-12)
        checked += 1
    assert checked >= 2 * edges.n_edges          # every copy of every edge


@pytest.mark.parametrize("order,ratio", [(2, 0.6), (3, 0.5), (4, 0.5)])
def test_weighted_edges_lower_the_condition_number(order, ratio):
    # measured (unit square maxh 0.05, 40 METIS parts, scaling "diagonal"), vertices -> vertices+edges:
    # order 2: 3.29 -> 1.68 (0.51), order 3: 4.09 -> 1.73 (0.42), order 4: 4.75 -> 1.85 (0.39); with the
    # unweighted (nodal) edge averages the ratios were about 0.94 (order 1, nodal: 2.35 -> 1.55, 0.66)
    _, a, f = poisson(order, 0.05)
    conds = []
    for primal in ("vertices", "vertices+edges"):
        inv = DDInverse(a, parts=40, primal=primal, cond=True, rtol=1e-10)
        inv.solve(f.vec.FV().NumPy())
        conds.append(inv.cond)
    assert conds[1] < ratio * conds[0]


def test_weighted_edges_stay_bounded_with_more_parts():
    # order 2, unit square maxh 0.03 (5277 dofs), 40 -> 300 METIS parts; measured: vertices 3.78 -> 3.71,
    # vertices+edges 1.64 -> 2.60 (x 1.59; the 300 parts have about 18 dofs each, so irregular)
    _, a, f = poisson(2, 0.03)
    cond = {}
    for parts in (40, 300):
        for primal in ("vertices", "vertices+edges"):
            inv = DDInverse(a, parts=parts, primal=primal, cond=True, rtol=1e-10)
            inv.solve(f.vec.FV().NumPy())
            cond[parts, primal] = inv.cond
    assert cond[300, "vertices+edges"] < 2.0 * cond[40, "vertices+edges"]
    assert cond[300, "vertices+edges"] < 0.8 * cond[300, "vertices"]


@pytest.mark.parametrize("order", [1, 2, 3])
def test_edge_numbers_of_a_refined_mesh_are_the_facet_dofs(order, caplog):
    """netgen's Refine() keeps the coarse edges in mesh.nedge; the facet space numbers the fine edges
    only. The vectorised numbers must be the facet dofs, without the ConvertOperator fallback."""
    ngmesh = unit_square.GenerateMesh(maxh=0.3)
    ngmesh.Refine()
    ngmesh.Refine()
    mesh = ngs.Mesh(ngmesh)
    F = ngs.FacetFESpace(mesh, order=0)
    assert mesh.nedge > F.ndof                     # the case: unused coarse edges
    V = vertex_table(mesh)
    with caplog.at_level("INFO", logger="ddsolve.ngsolve.local"):
        number = mesh_edge_numbers(mesh, V, element_dofs(ngs.H1(mesh, order=order)), order)
    assert "ConvertOperator" not in caplog.text
    expected = np.array([sorted(F.GetDofNrs(ngs.ElementId(ngs.VOL, e))) for e in range(mesh.ne)])
    np.testing.assert_array_equal(np.sort(number, axis=1), expected)
