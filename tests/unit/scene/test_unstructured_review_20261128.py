"""scene_from_mesh defects a black-box review (2026-11-28) reproduced (Python API on a user's mesh)."""
from __future__ import annotations

import pytest

pytest.importorskip("ngsolve")

from ddsolve.errors import InputError
from ddsolve.scene.unstructured import mesh_geometry, scene_from_mesh


def test_refine_leaves_the_callers_mesh_alone():
    """refine > 0 refined the caller's netgen mesh in place: the same call gave 4x the triangles each time."""
    mesh = mesh_geometry("poisson", maxh=0.3)
    before = len(mesh.Elements2D())
    first = scene_from_mesh(mesh, parts=2, refine=1)
    second = scene_from_mesh(mesh, parts=2, refine=1)
    assert len(mesh.Elements2D()) == before
    assert len(first.elements) == len(second.elements) == 4 * before


def test_a_material_listed_twice_is_refused():
    """bodies=(m1, m2, m1) was read as two bodies (index() takes the first)."""
    mesh = mesh_geometry("contact", maxh=0.3)
    with pytest.raises(InputError, match=r"^bodies: material 'body0' is listed twice"):
        scene_from_mesh(mesh, bodies=["body0", "body1", "body0"], parts=2)
