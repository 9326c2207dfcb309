"""DDInverse on 3D tetrahedral meshes, against NGSolve's direct inverse of the same discrete problem."""
from __future__ import annotations

import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.csg import CSGeometry, OrthoBrick, Pnt, Sphere, unit_cube
from test_ddinverse import dd, direct, forms, relerr

from ddsolve.errors import InputError
from ddsolve.ngsolve import DDInverse
from ddsolve.ngsolve.dofs import vertex_table
from ddsolve.ngsolve.facets import boundary_vertices, facet_graph, facet_owner


@pytest.fixture(scope="module")
def cube():
    return ngs.Mesh(unit_cube.GenerateMesh(maxh=0.22))


def cube_with_hole(maxh: float):
    geo = CSGeometry()
    geo.Add(OrthoBrick(Pnt(0, 0, 0), Pnt(1, 1, 1)).bc("outer") - Sphere(Pnt(0.5, 0.5, 0.5), 0.25).bc("hole"))
    return ngs.Mesh(geo.GenerateMesh(maxh=maxh))


def two_materials(maxh: float):
    geo = CSGeometry()
    box = OrthoBrick(Pnt(0, 0, 0), Pnt(1, 1, 1)).bc("outer")
    half = OrthoBrick(Pnt(-1, -1, -1), Pnt(0.5, 2, 2))
    geo.Add((box * half).mat("soft"))
    geo.Add((box - half).mat("stiff"))
    return ngs.Mesh(geo.GenerateMesh(maxh=maxh))


def forms3d(mesh, order, coef, reaction=0.0, dirichlet=".*"):
    return forms(mesh, order, coef, reaction, dirichlet, load=1 + ngs.x * ngs.y - ngs.z)


@pytest.mark.parametrize("order", [1, 2, 3])
@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_cube_variable_coefficient(cube, order, method):
    fes, a, f = forms3d(cube, order, 1 + 10 * ngs.IfPos(ngs.x - 0.4, 1, 0) + ngs.y * ngs.z,
                        dirichlet="left|back")
    x, inv = dd(fes, a, f, method=method, parts=10)
    assert inv.converged and inv.n_parts >= 10
    assert relerr(x, direct(fes, a, f)) < 1e-8
    assert inv.iterations < (45 if method == "feti" else 25)


@pytest.mark.parametrize("order", [1, 2])
def test_reaction_diffusion_without_dirichlet(order):
    """No Dirichlet dof at all: the reaction term makes every part's matrix definite (no floating parts)."""
    mesh = cube_with_hole(0.25)
    fes, a, f = forms3d(mesh, order, 1.0, reaction=3.0 + ngs.x, dirichlet="")
    for method in ("bddc", "fetidp", "feti"):
        x, inv = dd(fes, a, f, method=method, parts=8)
        assert inv.converged
        assert relerr(x, direct(fes, a, f)) < 1e-8


@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_robin_faces(method):
    """A ds integrator on boundary faces is added to the tetrahedra those faces bound."""
    mesh = cube_with_hole(0.25)
    fes, a, f = forms3d(mesh, 2, 1.0 + ngs.z, dirichlet="")
    u, v = fes.TnT()
    a += (2.0 + ngs.x) * u * v * ngs.ds("hole")
    x, inv = dd(fes, a, f, method=method, parts=8)
    assert inv.converged
    assert relerr(x, direct(fes, a, f)) < 1e-8


def test_materials_and_explicit_partition():
    mesh = two_materials(0.2)
    coef = mesh.MaterialCF({"soft": 1.0, "stiff": 1e3})
    fes, a, f = forms3d(mesh, 2, coef)
    ref = direct(fes, a, f)
    x, inv = dd(fes, a, f, partition="materials")
    assert inv.n_parts == 2 and relerr(x, ref) < 1e-8
    V = vertex_table(mesh)
    centroids = np.asarray(mesh.ngmesh.Coordinates())[V].mean(axis=1)
    label = (centroids[:, 0] > 0.5).astype(int) * 2 + (centroids[:, 2] > 0.5).astype(int)
    x, inv = dd(fes, a, f, partition=label, method="fetidp")
    assert inv.n_parts == 4 and relerr(x, ref) < 1e-8


def test_coarse_partition_of_a_refined_mesh():
    """partition="coarse" reads netgen's parentelements in 3D: every part is a union of coarse tetrahedra."""
    from ddsolve.ngsolve.local import refinement_roots

    coarse = ngs.Mesh(unit_cube.GenerateMesh(maxh=0.4))
    mesh = ngs.Mesh(unit_cube.GenerateMesh(maxh=0.4))
    mesh.Refine()
    root = refinement_roots(mesh)
    assert np.unique(root).size == coarse.ne
    centroids = np.asarray(mesh.ngmesh.Coordinates())[vertex_table(mesh)].mean(axis=1)
    located = np.array([coarse(*map(float, c)).nr for c in centroids[::5]])
    np.testing.assert_array_equal(root[::5], located)
    fes, a, f = forms3d(mesh, 1, 1 + ngs.x)
    x, inv = dd(fes, a, f, parts=6, partition="coarse")
    assert inv.n_parts >= 6 and relerr(x, direct(fes, a, f)) < 1e-8


def test_primal_dofs_are_the_subdomain_edges(cube):
    """In 3D every dof shared by three or more parts is primal; the coarse space keeps the
    condition number small and nearly independent of the number of parts."""
    fes, a, f = forms3d(cube, 2, 1.0)
    conds = []
    for parts in (8, 24):
        x, inv = dd(fes, a, f, parts=parts, cond=True)
        sub = inv.sub
        assert relerr(x, direct(fes, a, f)) < 1e-8
        assert np.all(sub.vertex[sub.multiplicity >= 3]) and (sub.multiplicity >= 3).sum() > 0
        conds.append(inv.cond)
    assert 1.0 < conds[0] < 3.0 and 1.0 < conds[1] < 3.0


def test_deluxe_in_3d():
    """Parts that cut a 3D checkerboard of 1e4: deluxe scaling is robust where diagonal weights are not
    (measured: cond 1,047 against 2.07)."""
    mesh = ngs.Mesh(unit_cube.GenerateMesh(maxh=0.2))
    coef = 1 + 1e4 * ngs.IfPos(ngs.sin(7 * ngs.x) * ngs.sin(7 * ngs.y) * ngs.sin(7 * ngs.z), 1, 0)
    fes, a, f = forms3d(mesh, 2, coef)
    ref = direct(fes, a, f)
    x_diag, diag = dd(fes, a, f, parts=12, cond=True, seed=1)
    x_dlx, dlx = dd(fes, a, f, parts=12, cond=True, seed=1, scaling="deluxe")
    assert relerr(x_diag, ref) < 1e-8 and relerr(x_dlx, ref) < 1e-8
    assert diag.cond > 100 and dlx.cond < 10
    assert dlx.iterations < diag.iterations


def test_bad_input_in_3d(cube):
    _, a, _ = forms3d(cube, 1, 1.0)
    with pytest.raises(InputError, match=r"primal: .vertices\+edges. needs method .bddc. or .fetidp."):
        DDInverse(a, primal="vertices+edges", method="feti")
    with pytest.raises(InputError, match=f"parts: {cube.ne + 1} parts requested"):
        DDInverse(a, parts=cube.ne + 1)


@pytest.mark.parametrize("order, method, condense", [(1, "bddc", False), (2, "fetidp", False), (2, "feti", False),
                                                     (3, "bddc", True)])
def test_hexahedral_mesh(order, method, condense):
    """Hexahedra (MakeStructured3DMesh's default; they were refused): against sparsecholesky, energy norm
    (the dof vector of a high-order 3D basis is ill-conditioned, docs/ngsolve.md), a Robin term included."""
    from ngsolve.meshes import MakeStructured3DMesh

    mesh = MakeStructured3DMesh(hexes=True, nx=6, ny=6, nz=6, mapping=lambda x, y, z: (x + 0.1 * y * z, y, z))
    fes = ngs.H1(mesh, order=order, dirichlet="left|bottom")
    u, v = fes.TnT()
    terms = (1 + ngs.x) * ngs.grad(u) * ngs.grad(v) * ngs.dx + u * v * ngs.ds("right")
    f = ngs.LinearForm((1 + ngs.y) * v * ngs.dx).Assemble()
    inv = DDInverse(ngs.BilinearForm(terms, condense=condense), parts=8, method=method, rtol=1e-10)
    a = ngs.BilinearForm(terms, condense=condense).Assemble()
    ref = (a.mat.Inverse(fes.FreeDofs(condense), inverse="sparsecholesky") * f.vec).Evaluate()
    got = (inv * f.vec).Evaluate()
    full = ngs.BilinearForm(terms).Assemble()
    d = ref.CreateVector()
    d.data = ref - got
    energy = np.sqrt(ngs.InnerProduct(full.mat * d, d) / ngs.InnerProduct(full.mat * ref, ref))
    assert inv.converged and inv.n_parts == 8 and energy < 1e-9


@pytest.mark.parametrize("hexes", [True, False])
def test_second_order_meshes(hexes):
    """20-node hexahedra and 10-node tetrahedra (secondorder=True) list edge nodes after the vertices: they
    were refused as prisms or mixed meshes (a review). Energy error against sparsecholesky."""
    from ngsolve.meshes import MakeStructured3DMesh

    mesh = MakeStructured3DMesh(hexes=hexes, nx=4, ny=4, nz=4, secondorder=True,
                                mapping=lambda x, y, z: (x + 0.1 * y, y, z + 0.05 * x * y))
    fes = ngs.H1(mesh, order=2, dirichlet="back")
    u, v = fes.TnT()
    terms = (1 + ngs.x) * ngs.grad(u) * ngs.grad(v) * ngs.dx
    f = ngs.LinearForm(v * ngs.dx).Assemble()
    inv = DDInverse(ngs.BilinearForm(terms), parts=4, rtol=1e-10)
    a = ngs.BilinearForm(terms).Assemble()
    ref = (a.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky") * f.vec).Evaluate()
    d = ref.CreateVector()
    d.data = ref - (inv * f.vec).Evaluate()
    assert inv.converged and np.sqrt(ngs.InnerProduct(a.mat * d, d) / ngs.InnerProduct(a.mat * ref, ref)) < 1e-9


def test_prisms_and_mixed_meshes_are_refused():
    from ngsolve.meshes import MakeStructured3DMesh

    mesh = MakeStructured3DMesh(hexes=False, prism=True, nx=2, ny=2, nz=2)
    fes = ngs.H1(mesh, order=1, dirichlet=".*")
    u, v = fes.TnT()
    with pytest.raises(InputError, match="mesh: only tetrahedral or hexahedral 3D meshes are supported"):
        DDInverse(ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx), parts=2)


def test_facets_of_two_hexahedra():
    # two unit cubes side by side in x, netgen's order (bottom face around, then the four above)
    V = np.array([[0, 1, 4, 3, 6, 7, 10, 9], [1, 2, 5, 4, 7, 8, 11, 10]])
    first, second = facet_graph(V, 3)
    np.testing.assert_array_equal(first, [0])
    np.testing.assert_array_equal(second, [1])
    assert boundary_vertices(V, 3, 12).all()            # every vertex lies on an outer face


def test_facets_of_two_tetrahedra():
    V = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    first, second = facet_graph(V, 3)
    np.testing.assert_array_equal(first, [0])
    np.testing.assert_array_equal(second, [1])
    # every vertex lies on an outer face (the shared face 1-2-3 is inner, its vertices on outer ones too)
    assert boundary_vertices(V, 3, 6).tolist() == [True] * 5 + [False]
    np.testing.assert_array_equal(facet_owner(V, 3, np.array([[3, 2, 0], [4, 3, 1]])), [0, 1])
    with pytest.raises(InputError, match="does not lie on a facet"):
        facet_owner(V, 3, np.array([[0, 1, 4]]))


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_vectorised_tetrahedron_table_is_ngsolves(order):
    """The element-to-dof table built from the vertex table equals the one of ConvertOperator."""
    from ngsolve.meshes import MakeStructured3DMesh

    from ddsolve.ngsolve.dofs import _converted_dofs, _tetrahedron_dofs

    for mesh in (ngs.Mesh(unit_cube.GenerateMesh(maxh=0.3)), MakeStructured3DMesh(hexes=False, nx=2, ny=3, nz=2)):
        fes = ngs.H1(mesh, order=order)
        table = _tetrahedron_dofs(fes, vertex_table(mesh))
        assert table is not None
        np.testing.assert_array_equal(table, _converted_dofs(fes))
