"""Black-box review of DDInverse's 3D edge averages (``primal="vertices+edges"``): degenerate
partitions (closed boundary loops without end vertices, parts touching at an edge or a vertex),
NGSolve's CGSolver, several right-hand sides, a non-converging case, and a partition without
any dual face (deluxe scaling used to raise IndexError there). Structured tetrahedral meshes,
compared with NGSolve's sparse Cholesky."""
from __future__ import annotations

import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from ngsolve.krylovspace import CGSolver
from ngsolve.meshes import MakeStructured3DMesh

from ddsolve.ngsolve import DDInverse

EDGES = "vertices+edges"


def forms(mesh, order, coef=1.0, dirichlet="left", reaction=None):
    fes = ngs.H1(mesh, order=order, dirichlet=dirichlet)
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += coef * ngs.grad(u) * ngs.grad(v) * ngs.dx
    if reaction is not None:
        a += reaction * u * v * ngs.dx
    f = ngs.LinearForm((1 + ngs.x * ngs.y + ngs.z) * v * ngs.dx)
    a.Assemble()
    f.Assemble()
    return fes, a, f


def direct(fes, a, vec):
    return (a.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky") * vec).Evaluate().FV().NumPy().copy()


def apply(inv, vec):
    return (inv * vec).Evaluate().FV().NumPy().copy()


def relerr(x, y):
    return np.linalg.norm(x - y) / np.linalg.norm(y)


def centroids(mesh):
    pts = np.array([v.point for v in mesh.vertices])
    cells = np.array([[v.nr for v in el.vertices] for el in mesh.Elements(ngs.VOL)])
    return pts[cells].mean(axis=1)


@pytest.fixture(scope="module")
def cube6():
    return MakeStructured3DMesh(hexes=False, nx=6, ny=6, nz=6)


@pytest.mark.parametrize("primal", ["vertices", EDGES])
@pytest.mark.parametrize("method", ["bddc", "fetidp"])
def test_deluxe_without_any_dual_face(method, primal):
    """One layer of P1 tetrahedra: every node is on the boundary, so with primal="vertices" every
    interface dof is primal and deluxe has no face (was IndexError in deluxe_scaling)."""
    mesh = MakeStructured3DMesh(hexes=False, nx=6, ny=6, nz=1)
    fes, a, f = forms(mesh, 1)
    inv = DDInverse(a, method=method, parts=4, primal=primal, scaling="deluxe", rtol=1e-12)
    x = apply(inv, f.vec)
    assert inv.n_parts == 4 and inv.converged
    assert relerr(x, direct(fes, a, f.vec)) < 1e-10
    if primal == "vertices":
        assert inv.iterations <= 1          # nothing dual: the coarse problem solves it


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("method", ["bddc", "fetidp"])
def test_slices_whose_edges_are_closed_loops(order, method):
    """Four x-slices, Dirichlet on x=0 only: each interface meets the boundary in a closed loop of
    nodes shared by two parts (an edge without end vertices), the only primal of the floating
    slices. Measured: cond 1.77 (P1) and 2.70 (P2), 10-11 iterations."""
    mesh = MakeStructured3DMesh(hexes=False, nx=8, ny=4, nz=4)
    part = np.minimum((centroids(mesh)[:, 0] * 4).astype(int), 3)
    fes, a, f = forms(mesh, order, coef=1 + ngs.x * ngs.y)
    inv = DDInverse(a, method=method, partition=part, primal=EDGES, rtol=1e-10, cond=True)
    x = apply(inv, f.vec)
    assert inv.n_parts == 4 and inv.converged
    assert relerr(x, direct(fes, a, f.vec)) < 1e-8
    assert inv.cond < 3.5 and inv.iterations <= 15


@pytest.mark.parametrize("layout", ["vertex", "edge", "octants"])
@pytest.mark.parametrize("method", ["bddc", "fetidp"])
def test_parts_touching_at_a_vertex_or_an_edge(cube6, layout, method):
    """No Dirichlet dof (reaction term). "vertex": octants 0 and 7 (one part, split in two
    pieces that touch each other at the centre only) and the rest; "edge": two diagonal
    columns touching along x = y = 1/2 and the rest (split in two). Measured cond 1.93 / 1.94 / 2.21."""
    c = centroids(cube6)
    octant = ((c[:, 0] > 0.5) * 4 + (c[:, 1] > 0.5) * 2 + (c[:, 2] > 0.5)).astype(int)
    column = ((c[:, 0] > 0.5) * 1 + (c[:, 1] > 0.5) * 2).astype(int)
    part, n_parts = {
        "vertex": (np.where((octant == 0) | (octant == 7), 0, 1), 3),
        "edge": (np.where(column == 0, 0, np.where(column == 3, 1, 2)), 4),
        "octants": (octant, 8),
    }[layout]
    fes, a, f = forms(cube6, 2, dirichlet="", reaction=1.0)
    inv = DDInverse(a, method=method, partition=part, primal=EDGES, rtol=1e-10, cond=True)
    x = apply(inv, f.vec)
    assert inv.n_parts == n_parts and inv.converged
    assert relerr(x, direct(fes, a, f.vec)) < 1e-8
    assert inv.cond < 3.0 and inv.iterations <= 18


def test_preconditioner_in_cgsolver_and_several_rhs(cube6):
    """Order 3 (bubbles condensed), 12 METIS parts: one inverse, three random right-hand sides,
    and its BDDC preconditioner in NGSolve's CG (measured 24 CG iterations, 20 FETI-DP)."""
    fes, a, f = forms(cube6, 3, coef=1 + ngs.x, dirichlet="left|bottom")
    inv = DDInverse(a, method="fetidp", parts=12, primal=EDGES, rtol=1e-10)
    cg = CGSolver(a.mat, inv.preconditioner, tol=1e-12, maxiter=100)
    x = (cg * f.vec).Evaluate().FV().NumPy()
    assert cg.iterations <= 35
    assert relerr(x, direct(fes, a, f.vec)) < 1e-8
    rng = np.random.default_rng(7)
    for _ in range(3):
        r = a.mat.CreateColVector()
        r.FV().NumPy()[:] = rng.standard_normal(fes.ndof)
        y = apply(inv, r)
        assert inv.converged and inv.iterations <= 30
        assert relerr(y, direct(fes, a, r)) < 1e-8


def test_non_convergence_is_reported(cube6):
    """A 1e6 checkerboard cut by the METIS parts (the documented limit) with maxiter=20."""
    cb = ngs.IfPos(ngs.sin(4 * ngs.pi * ngs.x) * ngs.sin(4 * ngs.pi * ngs.y) * ngs.sin(4 * ngs.pi * ngs.z), 1e6, 1.0)
    fes, a, f = forms(cube6, 2, coef=cb, dirichlet=".*")
    inv = DDInverse(a, method="fetidp", parts=12, primal=EDGES, rtol=1e-10, maxiter=20)
    apply(inv, f.vec)
    assert not inv.converged and inv.iterations == 20
    assert inv.reason.startswith("maxiter 20 reached")
