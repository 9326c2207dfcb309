"""DDInverse on spaces with definedon=, ngsolve.Compress and ngsolve.Periodic, and a diagonal=True form.

Every solve is compared with NGSolve's sparse Cholesky of the same assembled form.
"""
import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.geom2d import SplineGeometry  # noqa: E402

from ddsolve.errors import InputError  # noqa: E402
from ddsolve.ngsolve import DDInverse  # noqa: E402
from ddsolve.ngsolve.dofs import active_elements, uncompressed  # noqa: E402

x, y = ngs.x, ngs.y


@pytest.fixture(scope="module")
def inclusion():
    """A 2 x 1 rectangle (material "outer") with a rectangular inclusion ("inner")."""
    geo = SplineGeometry()
    geo.AddRectangle((0, 0), (2, 1), leftdomain=1, rightdomain=0, bc="outer")
    geo.AddRectangle((0.5, 0.25), (1.5, 0.75), leftdomain=2, rightdomain=1, bc="inner")
    geo.SetMaterial(1, "outer")
    geo.SetMaterial(2, "inner")
    return ngs.Mesh(geo.GenerateMesh(maxh=0.06))


def periodic_square(both: bool, maxh: float = 0.08):
    """The unit square, periodic in x (bottom and top "outer"), or in x and y."""
    g = SplineGeometry()
    pn = [g.AppendPoint(*p) for p in [(0, 0), (1, 0), (1, 1), (0, 1)]]
    bottom = g.Append(["line", pn[0], pn[1]], bc="periodicy" if both else "outer")
    right = g.Append(["line", pn[1], pn[2]], bc="periodicx")
    if both:
        g.Append(["line", pn[3], pn[2]], leftdomain=0, rightdomain=1, copy=bottom, bc="periodicy")
    else:
        g.Append(["line", pn[2], pn[3]], bc="outer")
    g.Append(["line", pn[0], pn[3]], leftdomain=0, rightdomain=1, copy=right, bc="periodicx")
    return ngs.Mesh(g.GenerateMesh(maxh=maxh))


def compare(fes, terms, load, rtol=1e-10, **kw):
    """Relative 2-norm error of DDInverse against sparsecholesky, and the DDInverse."""
    u, v = fes.TnT()

    def form():
        a = ngs.BilinearForm(fes)
        a += terms(u, v)
        return a

    f = ngs.LinearForm(load * v * ngs.dx).Assemble()
    assembled = form().Assemble()
    ref = assembled.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky") * f.vec
    inv = DDInverse(form(), rtol=rtol, **kw)          # the unassembled form
    got = (inv * f.vec).Evaluate()
    r = np.array(ref.Evaluate().FV().NumPy())
    return np.linalg.norm(r - got.FV().NumPy()) / np.linalg.norm(r), inv


def laplace_robin(u, v):
    return (1 + x * y) * ngs.grad(u) * ngs.grad(v) * ngs.dx + u * v * ngs.ds("outer")


@pytest.mark.parametrize("region, dirichlet", [("inner", "inner"), ("outer", "inner")])
@pytest.mark.parametrize("order", [1, 3])
@pytest.mark.parametrize("method, primal", [("bddc", "vertices"), ("fetidp", "vertices+edges"),
                                            ("feti", "vertices")])
def test_definedon_space_solves_its_materials_problem(inclusion, region, dirichlet, order, method, primal):
    fes = ngs.H1(inclusion, order=order, definedon=region, dirichlet=dirichlet)
    error, inv = compare(fes, laplace_robin, 1 + x, method=method, parts=6, primal=primal)
    assert inv.converged and error < 1e-9
    n_region = int(sum(inclusion.GetMaterials()[el.index] == region for el in inclusion.Elements(ngs.VOL)))
    assert inv.elements.size == n_region < inclusion.ne


def test_definedon_partitions_and_condensation(inclusion):
    fes = ngs.H1(inclusion, order=3, definedon="outer", dirichlet="outer")
    laplace = lambda u, v: ngs.grad(u) * ngs.grad(v) * ngs.dx       # noqa: E731
    error, inv = compare(fes, laplace, 1, partition="materials")
    assert inv.n_parts == 1 and error < 1e-12
    centre = np.array([sum(inclusion[vx].point[0] for vx in el.vertices) / 3 for el in inclusion.Elements(ngs.VOL)])
    labels = np.minimum((centre * 2).astype(int), 3)      # 4 strips; the middle two also hold the inclusion
    error, inv = compare(fes, laplace, 1, partition=labels)
    assert inv.converged and error < 1e-9
    # the strips are cut by the inclusion into their connected pieces: 1 + 2 + 2 + 1
    assert inv.n_parts == 6
    error, inv = compare(fes, laplace, 1, partition="coarse", parts=5)
    assert inv.converged and error < 1e-9
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes, condense=True)
    a += ngs.grad(u) * ngs.grad(v) * ngs.dx
    f = ngs.LinearForm(v * ngs.dx).Assemble()
    inv = DDInverse(a, parts=5, rtol=1e-10)
    a.Assemble()
    ref = a.mat.Inverse(fes.FreeDofs(True), inverse="sparsecholesky") * f.vec
    r = np.array(ref.Evaluate().FV().NumPy())
    assert np.linalg.norm(r - (inv * f.vec).Evaluate().FV().NumPy()) < 1e-9 * np.linalg.norm(r)
    with pytest.raises(InputError, match=r"^parts: .* the mesh of the space \(definedon=\) has only"):
        DDInverse(a, parts=inv.elements.size + 1)


def test_definedon_in_3d():
    from netgen.occ import X, Box, Glue, OCCGeometry

    inner = Box((0.5, 0.25, 0.25), (1.5, 0.75, 0.75)).mat("inner")
    outer = (Box((0, 0, 0), (2, 1, 1)) - inner).mat("outer")
    outer.faces.Min(X).name = "left"
    mesh = ngs.Mesh(OCCGeometry(Glue([outer, inner])).GenerateMesh(maxh=0.25))
    fes = ngs.H1(mesh, order=2, definedon="outer", dirichlet="left")
    error, inv = compare(fes, lambda u, v: ngs.grad(u) * ngs.grad(v) * ngs.dx, 1, parts=6)
    assert inv.converged and error < 1e-9 and inv.elements.size < mesh.ne


def test_full_and_boundary_spaces(inclusion):
    assert active_elements(ngs.H1(inclusion, order=2)) is None
    assert active_elements(ngs.H1(inclusion, order=2, definedon="inner|outer")) is None
    boundary = ngs.H1(inclusion, definedon=inclusion.Boundaries("outer"))
    u, v = boundary.TnT()
    with pytest.raises(InputError, match=r"^fes: the space has no dofs on the volume elements"):
        DDInverse(ngs.BilinearForm(u * v * ngs.ds))


@pytest.mark.parametrize("order", [1, 3])
def test_compressed_spaces(inclusion, order):
    spaces = {"default": ngs.Compress(ngs.H1(inclusion, order=order, dirichlet="inner")),
              "definedon": ngs.Compress(ngs.H1(inclusion, order=order, definedon="outer", dirichlet="inner"))}
    base = ngs.H1(inclusion, order=order, dirichlet="inner|outer")
    spaces["active_dofs"] = ngs.Compress(base, active_dofs=base.FreeDofs())
    for name, fes in spaces.items():
        space, dofs = uncompressed(fes)
        assert dofs.size == fes.ndof and np.all(np.diff(dofs) > 0), name
        assert (fes.ndof == space.ndof) if name == "default" else (fes.ndof < space.ndof), name
        error, inv = compare(fes, laplace_robin, 1 + x, parts=6)
        assert inv.converged and error < 1e-9, name
        assert inv.Height() == fes.ndof
        u, v = fes.TnT()
        a = ngs.BilinearForm(laplace_robin(u, v)).Assemble()
        f = ngs.LinearForm((1 + x) * v * ngs.dx).Assemble()
        cg = ngs.solvers.CGSolver(a.mat, inv.preconditioner, tol=1e-10, maxiter=100)
        ref = np.array((a.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky") * f.vec).Evaluate().FV().NumPy())
        got = (cg * f.vec).Evaluate().FV().NumPy()
        assert cg.iterations < 20 and np.linalg.norm(ref - got) < 1e-8 * np.linalg.norm(ref), name


@pytest.mark.parametrize("order", [1, 2, 4])
@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_periodic_in_x(order, method):
    mesh = periodic_square(both=False)
    fes = ngs.Periodic(ngs.H1(mesh, order=order, dirichlet="outer"))
    error, inv = compare(fes, lambda u, v: (1 + 0.5 * ngs.sin(6 * x)) * ngs.grad(u) * ngs.grad(v) * ngs.dx,
                         1 + x + 3 * ngs.sin(7 * y), method=method, parts=9)
    assert inv.converged and error < 1e-9


def test_periodic_in_x_and_y_and_its_pure_neumann_form():
    mesh = periodic_square(both=True)
    fes = ngs.Periodic(ngs.H1(mesh, order=2))
    error, inv = compare(fes, lambda u, v: ngs.grad(u) * ngs.grad(v) * ngs.dx + u * v * ngs.dx,
                         1 + x + 3 * ngs.sin(7 * y), parts=9)
    assert inv.converged and error < 1e-9
    u, v = fes.TnT()
    with pytest.raises(InputError, match=r"^a: the form is singular on the mesh"):
        DDInverse(ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx), parts=4)


def test_periodic_cube():
    from netgen.occ import X, Z, Box, OCCGeometry

    cube = Box((0, 0, 0), (1, 1, 1))
    cube.faces.Min(X).Identify(cube.faces.Max(X), "periodic")
    cube.faces.Min(Z).name = "bottom"
    cube.faces.Max(Z).name = "top"
    mesh = ngs.Mesh(OCCGeometry(cube).GenerateMesh(maxh=0.2))
    fes = ngs.Periodic(ngs.H1(mesh, order=2, dirichlet="bottom|top"))
    error, inv = compare(fes, lambda u, v: (1 + x) * ngs.grad(u) * ngs.grad(v) * ngs.dx, 1 + ngs.sin(5 * x),
                         method="fetidp", parts=8)
    assert inv.converged and error < 1e-9


def test_a_diagonal_form_is_refused(inclusion):
    fes = ngs.H1(inclusion, order=1, dirichlet="outer")
    u, v = fes.TnT()
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx + u * v * ngs.dx, diagonal=True)
    with pytest.raises(InputError, match=r"^a: a form with diagonal=True is not supported"):
        DDInverse(a, parts=4)
    # diagonal=False is the ordinary form
    b = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx + u * v * ngs.dx, diagonal=False)
    assert DDInverse(b, parts=4).n_parts == 4


def test_periodic_table_is_ngsolves_on_every_element():
    """The element table of a periodic space reads the identified dofs on every element (the vectorised
    table, checked on a sample of elements only, would miss a periodic boundary the sample does not touch)."""
    from ddsolve.ngsolve.dofs import element_dofs

    mesh = periodic_square(both=True, maxh=0.05)
    fes = ngs.Periodic(ngs.H1(mesh, order=3))
    T = element_dofs(fes)
    expected = np.array([fes.GetDofNrs(ngs.ElementId(ngs.VOL, e)) for e in range(mesh.ne)])
    assert np.array_equal(T, expected)
    assert np.unique(T[:, :3]).size < mesh.nv          # the identified vertices are gone


def test_a_fes_numbering_the_dofs_otherwise_is_refused(inclusion):
    """Equal ndof is not the same system: a periodic fes for a non-periodic form (and the reverse), or
    another definedon= at order 1 (NGSolve numbers every vertex), was solved as given, reported converged."""
    mesh = periodic_square(both=False)
    plain, periodic = ngs.H1(mesh, order=2, dirichlet="outer"), ngs.Periodic(ngs.H1(mesh, order=2, dirichlet="outer"))
    assert plain.ndof == periodic.ndof
    for form_space, fes in ((plain, periodic), (periodic, plain)):
        u, v = form_space.TnT()
        with pytest.raises(InputError, match=r"^fes: numbers the dofs otherwise than the form's space"):
            DDInverse(ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx), fes=fes, parts=4)
    inner, outer = (ngs.H1(inclusion, order=1, definedon=r, dirichlet="outer|inner") for r in ("inner", "outer"))
    assert inner.ndof == outer.ndof
    u, v = inner.TnT()
    with pytest.raises(InputError, match=r"^fes: numbers the dofs otherwise"):
        DDInverse(ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx), fes=outer, parts=4)
    # another dirichlet= is what fes is for
    other = ngs.H1(inclusion, order=1, definedon="inner", dirichlet="inner")
    error, inv = compare(other, lambda u, v: ngs.grad(u) * ngs.grad(v) * ngs.dx, 1, parts=4)
    assert error < 1e-9
    a = ngs.BilinearForm(ngs.grad(inner.TrialFunction()) * ngs.grad(inner.TestFunction()) * ngs.dx)
    assert DDInverse(a, fes=other, parts=4).n_parts == 4


def test_pieces_joined_only_by_a_periodic_identification_are_one_piece():
    """Two rectangles, the right edge of B identified with the left edge of A, clamped on A's right edge
    only: positive definite (B is held through the identification); it was refused as singular on B."""
    from netgen.occ import X, Compound, IdentificationType, OCCGeometry, Rectangle

    A = Rectangle(0.4, 1).Face()
    B = Rectangle(0.4, 1).Face().Move((0.6, 0, 0))
    A.faces.name, B.faces.name = "A", "B"
    A.edges.Max(X).name, A.edges.Min(X).name = "Aright", "Aleft"
    B.edges.Max(X).name = "Bright"
    B.edges.Max(X).Identify(A.edges.Min(X), "per", IdentificationType.PERIODIC)
    mesh = ngs.Mesh(OCCGeometry(Compound([A, B]), dim=2).GenerateMesh(maxh=0.1))
    fes = ngs.Periodic(ngs.H1(mesh, order=2, dirichlet="Aright"))
    for kw in ({"parts": 6}, {"partition": "materials", "method": "feti"}):
        error, inv = compare(fes, lambda u, v: ngs.grad(u) * ngs.grad(v) * ngs.dx, 1 + y, **kw)
        assert inv.converged and error < 1e-9, kw


def test_condensed_form_with_a_dropped_cell_dof():
    """condense=True on Compress(..., active_dofs=...) dropping one cell dof: that element position is not
    condensed; the answer was right but the final check read those dofs as zero (not converged)."""
    from netgen.geom2d import unit_square

    mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=0.1))
    base = ngs.H1(mesh, order=3, dirichlet="left")
    local = [i for i in range(base.ndof) if base.CouplingType(i) == ngs.COUPLING_TYPE.LOCAL_DOF]
    active = ngs.BitArray(base.FreeDofs())
    active.Clear(local[0])
    fes = ngs.Compress(base, active_dofs=active)
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes, condense=True)
    a += ngs.grad(u) * ngs.grad(v) * ngs.dx
    f = ngs.LinearForm((1 + y) * v * ngs.dx).Assemble()
    inv = DDInverse(a, parts=8, rtol=1e-10)
    a.Assemble()
    ref = np.array((a.mat.Inverse(fes.FreeDofs(True), inverse="sparsecholesky") * f.vec).Evaluate().FV().NumPy())
    got = (inv * f.vec).Evaluate().FV().NumPy()
    assert inv.converged and inv.error_estimate < 1e-9, inv.reason
    assert np.linalg.norm(ref - got) < 1e-9 * np.linalg.norm(ref)
