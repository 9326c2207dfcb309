"""contact_solve on NGSolve meshes against the direct contact solve of the same discrete problem."""
from __future__ import annotations

import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.occ import MoveTo, OCCGeometry, X

from ddsolve.contact.direct import solve_contact_direct
from ddsolve.errors import InputError
from ddsolve.ngsolve import contact_solve
from conftest import two_squares

#: Dostal-like patch loads: -3 on the top strip of body 1, -1 on the bottom strip of body 2 (partial contact).
LOAD = ngs.IfPos(ngs.x - 1, ngs.IfPos(0.25 - ngs.y, -1.0, 0.0), ngs.IfPos(ngs.y - 0.75, -3.0, 0.0))


two_materials = two_squares      # left / right unit squares; wall, gap, far


def one_body(x0: float, maxh: float):
    face = MoveTo(x0, 0).Rectangle(1, 1).Face()
    face.faces.name = "body"
    face.edges.Min(X).name = "gap" if x0 == 1 else "wall"
    if x0 == 0:
        face.edges.Max(X).name = "gap"
    return ngs.Mesh(OCCGeometry(face, dim=2).GenerateMesh(maxh=maxh))


def centroid_check(res, body_meshes):
    """gfu at every element centroid equals the mean of the library's nodal values (P1 interpolant)."""
    prep = res.prepared
    scene, sub = prep.scene, prep.sub
    u_node = np.zeros(scene.n_nodes)
    free = sub.dof_of_node >= 0
    u_node[free] = res.u[sub.dof_of_node[free]]
    el_body = scene.subdomain_body[scene.element_subdomain]
    for k in range(2):
        els = scene.elements[el_body == k]
        c = scene.coords[els].mean(axis=1)
        expected = u_node[els].mean(axis=1)
        got = res.gfu[k](body_meshes[k](c[:, 0], c[:, 1])).ravel()
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * np.abs(u_node).max())


@pytest.mark.parametrize("method", ["active-set", "smalbe"])
def test_two_material_mesh_matches_direct(method):
    mesh = two_materials(0.1)
    res = contact_solve(mesh, ("left", "right"), contact="gap", dirichlet="wall", f=LOAD, method=method,
                        parts=3, rtol=1e-10)
    problem = res.prepared.contact
    ref = solve_contact_direct(problem)
    assert ref.converged and res.converged, res.reason
    assert 0 < res.active.sum() < res.active.size             # partial contact
    np.testing.assert_array_equal(res.active, ref.active)
    assert abs(res.energy - problem.energy(ref.u)) <= 1e-9 * abs(problem.energy(ref.u))
    assert res.kkt_residual <= 1e-8
    assert problem.kkt(res.u, res.multipliers).max <= 1e-8
    np.testing.assert_allclose(res.points[:, 0], 1.0, atol=1e-12)
    assert res.gap.min() >= -1e-8 * np.abs(res.u).max() and res.multipliers.min() >= 0
    assert np.abs(res.gap[res.active]).max() <= 1e-8 * np.abs(res.u).max()
    centroid_check(res, (mesh, mesh))
    # the GridFunctions live on their own material only
    assert res.gfu[0](mesh(1.5, 0.5)) == 0.0 and res.gfu[1](mesh(0.5, 0.5)) == 0.0


def test_direct_method_and_per_body_loads():
    mesh = two_materials(0.15)
    res = contact_solve(mesh, contact="gap", dirichlet="wall", f={"left": 0.5, "right": -1.0}, rho=(1.0, 10.0),
                        method="direct", parts=2)
    assert res.converged and res.iterations == 0
    assert res.kkt_residual <= 1e-8
    np.testing.assert_allclose(res.prepared.scene.rho, [1.0, 1.0, 10.0, 10.0])
    centroid_check(res, (mesh, mesh))


def test_two_meshes_conforming():
    m1, m2 = one_body(0, 0.125), one_body(1, 0.125)
    res = contact_solve((m1, m2), contact="gap", dirichlet="wall", f=LOAD, method="active-set", parts=2,
                        rtol=1e-10)
    ref = solve_contact_direct(res.prepared.contact)
    assert res.converged and res.kkt_residual <= 1e-8
    np.testing.assert_array_equal(res.active, ref.active)
    assert res.gfu[0].space.mesh is m1 and res.gfu[1].space.mesh is m2
    assert res.points.shape[0] == len([v for v in m1.vertices if abs(v.point[0] - 1) < 1e-12])
    centroid_check(res, (m1, m2))


def test_bad_input():
    mesh = two_materials(0.3)
    kw = {"contact": "gap", "dirichlet": "wall", "f": -1.0, "parts": 1, "method": "direct"}
    with pytest.raises(InputError, match="bodies: the mesh has no material named 'middle'"):
        contact_solve(mesh, ("left", "middle"), **kw)
    with pytest.raises(InputError, match=r"bodies: the two bodies must be two different materials, got \['left', 'left'\]"):
        contact_solve(mesh, ("left", "left"), **kw)
    with pytest.raises(InputError, match="contact: the mesh has no boundary named 'slit'"):
        contact_solve(mesh, **{**kw, "contact": "slit"})
    with pytest.raises(InputError, match="dirichlet: the mesh has no boundary named 'floor'"):
        contact_solve(mesh, **{**kw, "dirichlet": "floor"})
    with pytest.raises(InputError, match="f: body 2 .*floats"):
        contact_solve(mesh, **{**kw, "f": 1.0})
    with pytest.raises(InputError, match="method"):
        contact_solve(mesh, **{**kw, "method": "lu"})
    with pytest.raises(InputError, match="rho: unknown body 'top'"):
        contact_solve(mesh, **{**kw, "rho": {"top": 1.0}})
    for rho in (-1.0, (1.0, 0.0), {"left": 1.0, "right": float("nan")}):     # per body, not per subdomain
        with pytest.raises(InputError, match=r"^rho: must be (positive, got \[|finite, got nan)") as info:
            contact_solve(mesh, **{**kw, "rho": rho, "parts": 4})
        assert "subdomain" not in str(info.value)
    # contact boundary that is not between the two bodies
    with pytest.raises(InputError, match=r"contact: boundary 'wall' is not a conforming interface .*near \([-0-9.e]+, "):
        contact_solve(mesh, **{**kw, "contact": "wall", "dirichlet": "gap"})


def test_two_meshes_non_conforming():
    m1, m2 = one_body(0, 0.3), one_body(1, 0.13)
    with pytest.raises(InputError, match=r"contact: boundary 'gap' is not conforming: vertex \(1, "):
        contact_solve((m1, m2), contact="gap", dirichlet="wall", f=-1.0, method="direct", parts=1)
    with pytest.raises(InputError, match="contact: mesh 1 has no boundary named 'seam'"):
        contact_solve((m1, m2), contact="seam", dirichlet="wall", method="direct", parts=1)


@pytest.mark.parametrize("f, contact", [({"left": -1.0, "right": 1.0}, False), ({"left": -1.0, "right": -2.0}, True)])
def test_both_bodies_clamped(f, contact):
    """No floating body: the direct method kept one pair active whatever the loads (review 2026-11-25:
    converged=False with a negative multiplier where the bodies separate); it now agrees with the active
    set method, with and without contact. SMALBE (Chapter 6: body 2 floats) refuses the scene."""
    mesh = two_materials(0.1)
    res = {method: contact_solve(mesh, ("left", "right"), contact="gap", dirichlet="wall|far", f=f,
                                 method=method, parts=3, rtol=1e-10) for method in ("active-set", "direct")}
    for r in res.values():
        assert r.converged, r.reason
        assert r.kkt_residual <= 1e-8 and r.multipliers.min() >= 0
        assert r.gap.min() >= -1e-8 * np.abs(r.u).max()
    assert res["direct"].active.any() == contact
    np.testing.assert_array_equal(res["direct"].active, res["active-set"].active)
    e = res["direct"].energy
    assert abs(res["active-set"].energy - e) <= 1e-9 * abs(e)
    if not contact:        # the two unconstrained membranes, apart: the gap is positive everywhere
        assert res["direct"].gap.min() > 0.1 and np.all(res["direct"].multipliers == 0)
    with pytest.raises(InputError, match=r"^method: 'smalbe' \(Chapter 6\) needs body 1 clamped and body 2 "
                                         r"floating.*here body 1 is clamped and body 2 is clamped"):
        contact_solve(mesh, ("left", "right"), contact="gap", dirichlet="wall|far", f=f, method="smalbe")


@pytest.mark.parametrize("f", [0.0, ngs.CoefficientFunction(0), 0 * ngs.x, lambda x, y: 0])
@pytest.mark.parametrize("method", ["active-set", "direct"])
def test_a_zero_load_solves_to_zero(f, method):
    """A load NGSolve simplifies to zero (CF(0), 0 * x) raised NGSolve's 'Linearform must have TestFunction'
    (a review, 2026-11-28); the number 0 solved. Both bodies clamped: u = 0 and no contact force."""
    res = contact_solve(two_materials(0.2), ("left", "right"), contact="gap", dirichlet="wall|far", f=f,
                        method=method, parts=2)
    assert res.converged, res.reason
    assert np.abs(res.u).max() == 0.0 and np.abs(res.multipliers).max() == 0.0


def test_refused_meshes_and_loads():
    """A mesh with SetDeformation was solved on its undeformed vertices (u 56% off NGSolve's own assembly on the
    deformed mesh, reported converged); with two meshes a GridFunction of mesh 1 was read as 0 on mesh 2."""
    mesh = two_materials(0.2)
    deformation = ngs.GridFunction(ngs.VectorH1(mesh, order=1))
    deformation.Set(ngs.CoefficientFunction((0.5 * ngs.x, 0)))
    mesh.SetDeformation(deformation)
    with pytest.raises(InputError, match="^mesh: a mesh with SetDeformation is not supported"):
        contact_solve(mesh, ("left", "right"), contact="gap", dirichlet="wall|far")
    mesh.UnsetDeformation()
    assert contact_solve(mesh, ("left", "right"), contact="gap", dirichlet="wall|far", method="direct").converged
    m1, m2 = one_body(0, 0.2), one_body(1, 0.2)
    g = ngs.GridFunction(ngs.H1(m1, order=1))
    g.Set(-1.0)
    for f in (g, 1.0 * g, ngs.CoefficientFunction(g), ngs.IfPos(ngs.x - 0.5, g, -1.0)):   # a review, 2026-11-28:
        with pytest.raises(InputError, match="^f: reads a GridFunction, which lives on one mesh"):   # 1.0 * g passed
            contact_solve((m1, m2), contact="gap", dirichlet="wall", f=f, method="direct")
    assert contact_solve((m1, m2), contact="gap", dirichlet="wall", f=-1.0 + 0 * ngs.x, method="direct").converged
