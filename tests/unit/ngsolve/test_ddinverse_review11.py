"""DDInverse behaviour documented after a review (2026-11-28, third session)."""
from __future__ import annotations

import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.geom2d import unit_square

from ddsolve.ngsolve import DDInverse


@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_one_part_is_solved_directly_and_has_no_condition_estimate(method):
    """parts=1 leaves no interface: the interior solve is the answer, 0 iterations, and cond stays None (as
    docs/ngsolve.md says) although cond=True was asked; the answer is NGSolve's direct one."""
    mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=0.2))
    fes = ngs.H1(mesh, order=2, dirichlet="left|bottom")
    u, v = fes.TnT()
    a = ngs.BilinearForm((1 + ngs.x) * ngs.grad(u) * ngs.grad(v) * ngs.dx).Assemble()
    f = ngs.LinearForm(ngs.y * v * ngs.dx).Assemble()
    inv = DDInverse(a, method=method, parts=1, cond=True)
    gfu = ngs.GridFunction(fes)
    gfu.vec.data = inv * f.vec
    ref = ngs.GridFunction(fes)
    ref.vec.data = a.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky") * f.vec
    assert inv.converged and inv.iterations == 0 and inv.cond is None
    assert inv.reason == "no interface: solved directly"
    x, y = gfu.vec.FV().NumPy(), ref.vec.FV().NumPy()
    assert np.linalg.norm(x - y) <= 1e-12 * np.linalg.norm(y)
