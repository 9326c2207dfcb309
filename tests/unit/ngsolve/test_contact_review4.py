"""Regressions from a black-box review of contact_solve (2026-11-27).

Four wrong answers reported as converged (a load read across the contact line, a load on the wrong
mesh, contact vertices clamped in one body only, a contact name that did not restrict the contact
zone), a curved mesh solved as a straight one, and tracebacks instead of one InputError.
"""
from __future__ import annotations

import re

import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.occ import Glue, MoveTo, OCCGeometry

from ddsolve.errors import InputError
from ddsolve.ngsolve import contact_solve
from conftest import two_squares
from test_ngsolve_contact import two_materials     # the two unit squares: wall, gap, far


@pytest.fixture(scope="module")
def mesh():
    return two_materials(0.1)


def _solve(mesh, f, **kw):
    kw = {"contact": "gap", "dirichlet": "wall", "method": "direct", **kw}
    return contact_solve(mesh, ("left", "right"), f=f, **kw)


def _body_load(res, body: int) -> float:
    """The total load the scene gives a body: sum over its elements of int_e f (element load vectors or
    element-wise constants times the areas)."""
    scene = res.prepared.scene
    on = scene.subdomain_body[scene.element_subdomain] == body
    f = np.asarray(scene.f)
    if f.ndim == 2:
        return float(f[on].sum())
    p = scene.coords[scene.elements[on]]
    area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                        - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    return float((f[on] * area).sum())


@pytest.mark.parametrize("load", ["ifpos", "material", "callable", "gridfunction"])
def test_loads_that_jump_at_the_contact_line(mesh, load):
    """-3 on body 1 and -1 on body 2, written four ways, gives the pair load's solution. IfPos(x - 1, ...)
    was evaluated at the edge midpoints of NGSolve's order-2 rule, on the contact line, so body 2's interface
    elements received body 1's load (body 2's total load -1.028 instead of -1, u off by 9.6e-3); MaterialCF
    was read as -3 everywhere (energy -11.99 instead of -3.66)."""
    reference = _solve(mesh, (-3.0, -1.0))
    if load == "ifpos":
        f = ngs.IfPos(ngs.x - 1, -1.0, -3.0)
    elif load == "material":
        f = mesh.MaterialCF({"left": -3.0, "right": -1.0})
    elif load == "callable":
        f = lambda x, y: ngs.IfPos(x - 1, -1.0, -3.0)      # noqa: E731
    else:
        gf = ngs.GridFunction(ngs.L2(mesh, order=0))
        gf.Set(mesh.MaterialCF({"left": -3.0, "right": -1.0}))
        f = gf
    res = _solve(mesh, f)
    assert res.converged and reference.converged
    assert _body_load(res, 1) == pytest.approx(-1.0, rel=1e-12)      # body 2 is the unit square (1, 2) x (0, 1)
    assert _body_load(res, 0) == pytest.approx(-3.0, rel=1e-12)
    assert res.energy == pytest.approx(reference.energy, rel=1e-12)
    scale = np.abs(reference.u).max()
    np.testing.assert_allclose(res.u, reference.u, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(res.multipliers, reference.multipliers, rtol=0,
                               atol=1e-11 * np.abs(reference.multipliers).max())


def _vertex_table(mesh) -> np.ndarray:
    return np.asarray([[v.nr for v in el.vertices] for el in mesh.Elements(ngs.VOL)])


def test_smooth_load_is_integrated_exactly(mesh):
    """A linear load: the scene's element load vectors, summed onto the mesh vertices, equal NGSolve's
    LinearForm of the same function (both bodies together, whose copies of the contact vertices add up)."""
    res = _solve(mesh, ngs.x - 3 * ngs.y - 1)
    v = ngs.H1(mesh, order=1).TestFunction()
    exact = ngs.LinearForm((ngs.x - 3 * ngs.y - 1) * v * ngs.dx).Assemble().vec.FV().NumPy()
    nodal = np.zeros(mesh.nv)
    np.add.at(nodal, _vertex_table(mesh).ravel(), np.asarray(res.prepared.scene.f).ravel())
    np.testing.assert_allclose(nodal, exact, rtol=0, atol=1e-14 * np.abs(exact).max())


def _named(maxh: float, name_edge):
    """Two unit squares (materials left, right) glued at x = 1; edges named by ``name_edge(center)``."""
    return two_squares(maxh, name_edge)


def test_contact_vertex_clamped_in_one_body_only():
    """Clamping body 1's bottom edge clamps the contact vertex (1, 0) in body 1 only: its pair was dropped and
    body 2 passed 0.63 below body 1 there, reported converged. A one-sided constraint is refused."""
    def name(c):
        if abs(c.x - 1) < 1e-9:
            return "gap"
        if abs(c.y) < 1e-9 and c.x < 1:
            return "bottom1"
        return None
    m = _named(0.2, name)
    with pytest.raises(InputError, match=r"^dirichlet: 1 contact vertices are clamped in one body only, "
                                         r"e\.g\. \(1, 0\)"):
        contact_solve(m, ("left", "right"), contact="gap", dirichlet="bottom1", f=(-1.0, -1.0))


def test_interface_partly_named_contact():
    """The interface named 'gap' below y = 0.5 and 'glue' above: contact='gap' paired every interface vertex
    (the same answer as contact='glue'), since the pairs are every location the bodies share."""
    def name(c):
        if abs(c.x - 1) < 1e-9:
            return "gap" if c.y < 0.5 else "glue"
        if abs(c.x) < 1e-9:
            return "wall"
        return None
    left = MoveTo(0, 0).Rectangle(1, 1).Face()
    left.faces.name = "left"
    lower, upper = MoveTo(1, 0).Rectangle(1, 0.5).Face(), MoveTo(1, 0.5).Rectangle(1, 0.5).Face()
    lower.faces.name = upper.faces.name = "right"
    shape = Glue([left, lower, upper])
    for edge in shape.edges:
        if name(edge.center):
            edge.name = name(edge.center)
    m = ngs.Mesh(OCCGeometry(shape, dim=2).GenerateMesh(maxh=0.2))
    for contact in ("gap", "glue"):
        with pytest.raises(InputError, match=r"^contact: the bodies share \d+ edges off '" + contact + "'"):
            contact_solve(m, ("left", "right"), contact=contact, dirichlet="wall", f=(-3.0, -1.0))


def test_curved_mesh_is_refused():
    """Curve(2) was accepted and solved on the straight triangles (energy bit-identical to the uncurved mesh)."""
    m = two_materials(0.2)
    m.Curve(2)
    with pytest.raises(InputError, match=r"^mesh: curved elements \(mesh.Curve\(2\)\) are not supported"):
        _solve(m, (-3.0, -1.0))


@pytest.mark.parametrize(("f", "message"), [
    (ngs.CoefficientFunction(1j), r"^f: must be real"),
    (ngs.CoefficientFunction((1.0, 2.0)), r"^f: must be a scalar CoefficientFunction, got one of dimension 2"),
    (ngs.CoefficientFunction(float("nan")) * ngs.x, r"^f: is not finite on the mesh"),
    (lambda x, y: 1 / 0, r"^f: calling f\(x, y\) with NGSolve's coordinates failed: division by zero"),
])
def test_bad_loads(mesh, f, message):
    """Each was a TypeError, ValueError, AttributeError or an 'atol' InputError (not an argument)."""
    with pytest.raises(InputError, match=message):
        _solve(mesh, f, dirichlet="wall|far", method="active-set")


@pytest.mark.parametrize("seed", ["x", None, 1.5])
def test_bad_seed(mesh, seed):
    with pytest.raises(InputError, match=r"^seed: must be an integer"):
        _solve(mesh, (-3.0, -1.0), seed=seed)


def test_load_returning_a_number(mesh):
    """f(x, y) may return a number: the same as that constant (it raised AttributeError 'Norm')."""
    a, b = _solve(mesh, lambda x, y: -1.0), _solve(mesh, -1.0)
    assert a.converged and a.energy == pytest.approx(b.energy, rel=1e-12)


@pytest.mark.parametrize("kw, message", [
    ({"rho": ngs.CoefficientFunction(1.0)}, "rho: must be a number, a pair of numbers or a dict of them"),
    ({"bodies": "left"}, "bodies: expected two material names (a pair), got 'left'"),
    ({"rtol": "1e-8"}, "rtol: must be a number in (0, 1)"),
    ({"rtol": None}, "rtol: must be a number in (0, 1)"),
    ({"maxiter": "10"}, "maxiter: must be a positive integer"),
    ({"maxiter": None}, "maxiter: must be a positive integer"),
])
def test_bad_arguments_of_a_second_review(mesh, kw, message):
    """A review of 2026-11-28: rho as a CoefficientFunction got the message meant for f; bodies="left" was split
    into characters; rtol and maxiter as strings ran, and rtol=None used the spec's 1e-5, not the documented
    default 1e-8."""
    kw = {"bodies": ("left", "right"), **kw}
    with pytest.raises(InputError, match=re.escape(message)):
        contact_solve(mesh, kw.pop("bodies"), contact="gap", dirichlet="wall", **kw)
