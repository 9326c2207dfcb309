"""DDInverse against NGSolve's direct inverse of the same discrete problem."""
from __future__ import annotations

import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.geom2d import Circle, CSG2d, Rectangle, SplineGeometry, unit_square

from ddsolve.errors import InputError
from ddsolve.ngsolve import DDInverse


def lshape(maxh: float):
    geo = SplineGeometry()
    pts = [geo.AppendPoint(*p) for p in [(0, 0), (1, 0), (1, 1), (0.5, 1), (0.5, 0.5), (0, 0.5)]]
    for i in range(6):
        geo.Append(["line", pts[i], pts[(i + 1) % 6]], bc="outer")
    return ngs.Mesh(geo.GenerateMesh(maxh=maxh))


def holed(maxh: float):
    geo = CSG2d()
    geo.Add(Rectangle(pmin=(0, 0), pmax=(1, 1), bc="outer") - Circle(center=(0.5, 0.5), radius=0.2, bc="hole"))
    return ngs.Mesh(geo.GenerateMesh(maxh=maxh))


def two_materials(maxh: float):
    geo = SplineGeometry()
    geo.AddRectangle((0, 0), (0.5, 1), leftdomain=1, rightdomain=0, bcs=["b", "m", "t", "l"])
    geo.AddRectangle((0.5, 0), (1, 1), leftdomain=2, rightdomain=0, bcs=["b", "r", "t", "m"])
    geo.SetMaterial(1, "soft")
    geo.SetMaterial(2, "stiff")
    return ngs.Mesh(geo.GenerateMesh(maxh=maxh))


def forms(mesh, order, coef, reaction=0.0, dirichlet="outer", load=None):
    fes = ngs.H1(mesh, order=order, dirichlet=dirichlet)
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += coef * ngs.grad(u) * ngs.grad(v) * ngs.dx
    if reaction:
        a += reaction * u * v * ngs.dx
    f = ngs.LinearForm(fes)
    f += ((1 + ngs.x * ngs.y) if load is None else load) * v * ngs.dx
    f.Assemble()
    return fes, a, f


def direct(fes, a, f):
    a.Assemble()
    gfu = ngs.GridFunction(fes)
    gfu.vec.data = a.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky") * f.vec
    return gfu.vec.FV().NumPy().copy()


def dd(fes, a, f, **kw):
    inv = DDInverse(a, rtol=1e-10, **kw)
    gfu = ngs.GridFunction(fes)
    gfu.vec.data = inv * f.vec
    return gfu.vec.FV().NumPy().copy(), inv


def relerr(x, ref):
    return np.linalg.norm(x - ref) / np.linalg.norm(ref)


@pytest.mark.parametrize("order", [1, 2, 3])
@pytest.mark.parametrize("method", ["bddc", "fetidp"])
def test_lshape_variable_coefficient(order, method):
    mesh = lshape(0.08)
    fes, a, f = forms(mesh, order, 1 + 100 * ngs.IfPos(ngs.x - 0.3, 1, 0) + ngs.y)
    x, inv = dd(fes, a, f, method=method, parts=8)
    assert inv.converged
    assert relerr(x, direct(fes, a, f)) < 1e-8
    assert inv.iterations < 40
    assert set(inv.timings) >= {"partition", "assembly", "condense", "substructures", "setup", "solve"}


def test_feti_reaction_diffusion():
    """Reaction term: no floating kernel; one-level FETI must notice it (order 2)."""
    mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=0.1))
    fes, a, f = forms(mesh, 2, 1.0, reaction=10.0, dirichlet="")
    ref = direct(fes, a, f)
    for method in ("bddc", "fetidp", "feti"):
        x, _ = dd(fes, a, f, method=method, parts=6)
        assert relerr(x, ref) < 1e-8, method


@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_one_part_is_a_direct_solve(method):
    mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=0.2))
    fes, a, f = forms(mesh, 3, 1.0, dirichlet="left")
    x, inv = dd(fes, a, f, method=method, partition="materials")
    assert inv.n_parts == 1 and inv.iterations == 0 and inv.converged
    assert relerr(x, direct(fes, a, f)) < 1e-10


def test_square_with_hole_order3_bubbles():
    mesh = holed(0.1)
    fes, a, f = forms(mesh, 3, 1.0 + ngs.x, dirichlet="hole")
    x, inv = dd(fes, a, f, parts=10, cond=True)
    assert inv.cond_data.b.size == 1          # one bubble per P3 triangle, condensed
    assert relerr(x, direct(fes, a, f)) < 1e-8
    assert 1.0 <= inv.cond < 30.0


def test_materials_partition_and_coefficient_jump():
    mesh = two_materials(0.08)
    coef = mesh.MaterialCF({"soft": 1.0, "stiff": 1e4})
    fes, a, f = forms(mesh, 2, coef, dirichlet="l")
    x, inv = dd(fes, a, f, partition="materials")
    assert inv.n_parts == 2
    assert relerr(x, direct(fes, a, f)) < 1e-8


@pytest.mark.parametrize("order", [2, 3])
def test_preconditioner_in_ngsolve_cg(order):
    from ngsolve.krylovspace import CGSolver

    mesh = lshape(0.08)
    fes, a, f = forms(mesh, order, 1 + ngs.x)
    ref = direct(fes, a, f)                 # assembles a
    inv = DDInverse(a, parts=8)
    # P is symmetric on the free dofs (CG needs it): <x, P y> = <y, P x>
    rng = np.random.default_rng(0)
    free = np.array(fes.FreeDofs(), dtype=bool)
    x, y, px, py = (ngs.GridFunction(fes).vec for _ in range(4))
    x.FV().NumPy()[:] = rng.standard_normal(fes.ndof) * free
    y.FV().NumPy()[:] = rng.standard_normal(fes.ndof) * free
    px.data = inv.preconditioner * x
    py.data = inv.preconditioner * y
    assert abs(ngs.InnerProduct(x, py) - ngs.InnerProduct(y, px)) < 1e-10 * abs(ngs.InnerProduct(x, px))
    solver = CGSolver(a.mat, inv.preconditioner, tol=1e-12, maxiter=100)
    gfu = ngs.GridFunction(fes)
    gfu.vec.data = solver * f.vec
    assert solver.iterations < 30
    assert relerr(gfu.vec.FV().NumPy(), ref) < 1e-8


def test_iterations_bounded_in_parts():
    mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=0.03))
    fes, a, f = forms(mesh, 1, 1.0, dirichlet=".*")
    its = {}
    for parts in (4, 16):
        _, inv = dd(fes, a, f, parts=parts)
        its[parts] = inv.iterations
    assert its[16] <= 1.5 * its[4] + 2, its


# ---------------------------------------------------------------- bad input
def _small():
    return ngs.Mesh(unit_square.GenerateMesh(maxh=0.3))


@pytest.mark.parametrize("space, word", [(lambda m: ngs.L2(m, order=1), "L2"),
                                         (lambda m: ngs.VectorH1(m, order=1), "VectorH1"),
                                         (lambda m: ngs.H1(m) * ngs.H1(m), "ProductSpace")])
def test_bad_space(space, word):
    fes = space(_small())
    a = ngs.BilinearForm(fes)
    with pytest.raises(InputError, match=f"fes: .*{word}"):
        DDInverse(a)


def test_bad_partition_and_parts():
    mesh = _small()
    _, a, _ = forms(mesh, 1, 1.0)
    with pytest.raises(InputError, match="partition: expected"):
        DDInverse(a, partition=np.zeros(mesh.ne + 1, dtype=int))
    labels = np.zeros(mesh.ne, dtype=int)
    labels[0] = 2
    with pytest.raises(InputError, match="partition: 1 empty parts"):
        DDInverse(a, partition=labels)
    with pytest.raises(InputError, match="parts: .*only"):
        DDInverse(a, parts=mesh.ne + 1)
    with pytest.raises(InputError, match="method"):
        DDInverse(a, method="lu")


def test_nonsymmetric_form():
    fes = ngs.H1(_small(), order=1, dirichlet=".*")
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += (ngs.grad(u) * ngs.grad(v) + ngs.CF((1, 0)) * ngs.grad(u) * v) * ngs.dx
    with pytest.raises(InputError, match="a: the form is not symmetric"):
        DDInverse(a)


def test_coarse_partition_is_inherited_by_refinement():
    from ddsolve.ngsolve.dofs import vertex_table
    from ddsolve.ngsolve.local import refinement_roots

    coarse = ngs.Mesh(unit_square.GenerateMesh(maxh=0.1))
    mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=0.1))
    mesh.Refine()
    mesh.Refine()
    root = refinement_roots(mesh)
    centroids = np.asarray(mesh.ngmesh.Coordinates())[:, :2][vertex_table(mesh)].mean(axis=1)
    located = np.array([coarse(float(x), float(y)).nr for x, y in centroids[::7]])
    np.testing.assert_array_equal(root[::7], located)
    fes, a, f = forms(mesh, 2, 1 + ngs.x, dirichlet=".*")
    x, inv = dd(fes, a, f, parts=8, partition="coarse")
    assert inv.n_parts >= 8
    assert relerr(x, direct(fes, a, f)) < 1e-8
    with pytest.raises(InputError, match="parts: .*coarse mesh"):
        DDInverse(a, parts=coarse.ne + 1, partition="coarse")


def test_coarse_partition_without_hierarchy_says_so(caplog):
    """netgen's own ngmesh.Refine() keeps no parents: 'coarse' is then METIS on the mesh, and the log says so."""
    import logging

    ngmesh = unit_square.GenerateMesh(maxh=0.2)
    ngmesh.Refine()
    mesh = ngs.Mesh(ngmesh)
    fes, a, f = forms(mesh, 1, 1 + ngs.x, dirichlet=".*")
    with caplog.at_level(logging.INFO, logger="ddsolve.ngsolve.local"):
        x, inv = dd(fes, a, f, parts=4, partition="coarse")
    assert "no mesh.Refine() hierarchy" in caplog.text and inv.n_parts >= 4
    assert relerr(x, direct(fes, a, f)) < 1e-8


@pytest.mark.parametrize("order", [1, 3])
@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_robin_boundary_terms(order, method):
    """ds integrators (Robin on part of the boundary, a variable one elsewhere) are not dropped."""
    mesh = holed(0.1)
    fes, a, f = forms(mesh, order, 1.0 + ngs.x, dirichlet="")
    u, v = fes.TnT()
    a += 5.0 * u * v * ngs.ds("outer")
    a += (1 + ngs.y) * u * v * ngs.ds("hole")
    x, inv = dd(fes, a, f, method=method, parts=6)
    assert inv.converged
    assert relerr(x, direct(fes, a, f)) < 1e-8


@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_factorizations_happen_once_at_construction(method, monkeypatch):
    """Two Mults (and a preconditioner application) factor nothing: every method factors at construction."""
    import scipy.linalg
    import scipy.sparse.linalg

    count = {"n": 0}

    def counting(fn):
        def wrapped(*args, **kwargs):
            count["n"] += 1
            return fn(*args, **kwargs)
        return wrapped

    for module, name in ((scipy.sparse.linalg, "splu"), (scipy.linalg, "cho_factor"), (scipy.linalg, "lu_factor")):
        monkeypatch.setattr(module, name, counting(getattr(module, name)))
    mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=0.1))
    fes, a, f = forms(mesh, 2, 1.0 + ngs.x, dirichlet="left")     # floating parts for FETI
    inv = DDInverse(a, method=method, parts=6, rtol=1e-10)
    at_construction = count["n"]
    assert at_construction >= 2
    ref = direct(fes, a, f)
    gfu = ngs.GridFunction(fes)
    for scale in (1.0, 2.0):
        gfu.vec.data = inv * (scale * f.vec)
        assert relerr(gfu.vec.FV().NumPy(), scale * ref) < 1e-8
    gfu.vec.data = inv.preconditioner * f.vec
    assert count["n"] == at_construction


@pytest.mark.parametrize("order", [1, 2, 3])
def test_feti_floating_parts_any_order(order):
    """One-level FETI with floating parts: the kernel (constants) is 1 on the vertex dofs only."""
    mesh = lshape(0.1)
    fes, a, f = forms(mesh, order, 1 + 10 * ngs.IfPos(ngs.x - 0.5, 1, 0), dirichlet="")
    x, inv = dd(fes, a, f, method="feti", parts=8, freedofs=_left_free(fes))
    assert inv.converged and inv._feti.R is not None and inv._feti.R.shape[1] > 0
    assert relerr(x, _direct_on(fes, a, f, _left_free(fes))) < 1e-8


def _left_free(fes):
    """Free dofs of the L-shape with u = 0 on its left side x = 0 only (most parts float)."""
    free = np.ones(fes.ndof, dtype=bool)
    for el in fes.mesh.Elements(ngs.BND):
        if all(abs(fes.mesh[v].point[0]) < 1e-12 for v in el.vertices):
            free[list(fes.GetDofNrs(el))] = False
    return free


def _direct_on(fes, a, f, free):
    a.Assemble()
    mask = ngs.BitArray([bool(b) for b in free])
    gfu = ngs.GridFunction(fes)
    gfu.vec.data = a.mat.Inverse(mask, inverse="sparsecholesky") * f.vec
    return gfu.vec.FV().NumPy().copy()
