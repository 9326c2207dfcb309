"""Regressions from the second black-box review of ddsolve.ngsolve (2026-11-25).

Each case was a wrong answer reported as converged, or a traceback instead of one InputError.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.geom2d import unit_square
from ngsolve.meshes import MakeStructured2DMesh

import ddsolve.ngsolve.inverse as inverse_module
from ddsolve.errors import ConvergenceWarning, InputError
from ddsolve.ngsolve import DDInverse


@pytest.fixture(scope="module")
def mesh():
    return ngs.Mesh(unit_square.GenerateMesh(maxh=0.05))


@pytest.fixture(scope="module")
def structured_mesh():
    """A mesh that is the same on every machine (netgen's meshing of the unit square differs between CPUs:
    the numbers of the coefficient-jump test below moved across its limits on another machine)."""
    from ngsolve.meshes import MakeStructured2DMesh

    return MakeStructured2DMesh(quads=False, nx=24, ny=24)


def _solve(op, f):
    out = f.CreateVector()
    out.data = op * f
    return out.FV().NumPy().copy()


def test_form_nonsymmetric_on_a_few_elements_is_refused(mesh):
    """Convection on about 4 of ~900 elements: the sampled check (32 elements) let it through and the
    solve 'converged' to an error of 2e-2; every element matrix is now checked."""
    fes = ngs.H1(mesh, order=1, dirichlet=".*")
    u, v = fes.TnT()
    spot = ngs.IfPos(0.03 ** 2 - (ngs.x - 0.37) ** 2 - (ngs.y - 0.61) ** 2, 1, 0)
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx + 5 * spot * ngs.grad(u)[0] * v * ngs.dx)
    with pytest.raises(InputError, match=r"^a: the form is not symmetric"):
        DDInverse(a, parts=8)


def test_form_nonsymmetric_through_a_ds_term_is_refused(mesh):
    fes = ngs.H1(mesh, order=2, dirichlet="left")
    u, v = fes.TnT()
    t = ngs.specialcf.tangential(2)
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx + 10 * u * v * ngs.ds("right")
                         + 0.5 * (ngs.grad(u).Trace() * t) * v * ngs.ds("right"))
    with pytest.raises(InputError, match=r"^a: the form is not symmetric"):
        DDInverse(a, parts=8)


def test_symmetric_check_reads_every_element():
    from ddsolve.ngsolve.dofs import is_symmetric

    rng = np.random.default_rng(5)
    Ke = rng.standard_normal((10_001, 6, 6))
    Ke = Ke + Ke.transpose(0, 2, 1)
    assert is_symmetric(Ke, chunk=4096)
    Ke[9_999, 1, 4] += 1e-7 * np.abs(Ke[9_999]).max()          # one element, in the last chunk
    assert not is_symmetric(Ke, chunk=4096)
    Ke[9_999, 1, 4] -= 1e-7 * np.abs(Ke[9_999]).max()
    Ke[17, 0, 5] *= 1 + 1e-13                                  # rounding: still symmetric
    assert is_symmetric(Ke, chunk=4096)


def test_point_integrator_is_refused(mesh):
    """u v on the BBND regions (corner points): it was dropped from the broken element matrices and the
    solve 'converged' to the answer of another problem (error 0.35)."""
    fes = ngs.H1(mesh, order=1, dirichlet="left")
    u, v = fes.TnT()
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx + u * v * ngs.comp.DifferentialSymbol(ngs.BBND))
    with pytest.raises(InputError, match=r"^a: integrator 1 lives on points or edges of the mesh"):
        DDInverse(a, parts=4)


@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_neumann_form_with_only_non_vertex_dofs_fixed_is_refused(mesh, method):
    """freedofs=FreeDofs(True) at order 3 fixes the bubbles only, so the constants stay in the kernel:
    fetidp returned converged=True with |u| ~ 1e14."""
    fes = ngs.H1(mesh, order=3)
    u, v = fes.TnT()
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx)
    with pytest.raises(InputError, match=r"^a: the form is singular"):
        DDInverse(a, method=method, parts=4, freedofs=fes.FreeDofs(True))


@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
def test_final_residual_check(mesh, method, monkeypatch):
    """The solve checks ||f - A u|| / ||f|| from the subdomain matrices. On a correct solve it equals the
    residual of the assembled matrix; on a singular problem that slipped past the input checks
    (here: the check switched off) the solve is not called converged."""
    fes = ngs.H1(mesh, order=2, dirichlet="left|bottom")
    u, v = fes.TnT()
    a = ngs.BilinearForm((1 + 10 * ngs.x) * ngs.grad(u) * ngs.grad(v) * ngs.dx + u * v * ngs.ds("right"))
    f = ngs.LinearForm(fes)
    f += (1 + ngs.y) * v * ngs.dx
    f.Assemble()
    inv = DDInverse(a, method=method, parts=8, rtol=1e-8)
    x = _solve(inv, f.vec)
    a.Assemble()
    free = np.array(fes.FreeDofs(), dtype=bool)
    ax = ngs.BaseVector(fes.ndof)
    gx = ngs.BaseVector(fes.ndof)
    gx.FV().NumPy()[:] = x
    ax.data = a.mat * gx
    r = (f.vec.FV().NumPy() - ax.FV().NumPy())[free]
    true = np.linalg.norm(r) / np.linalg.norm(f.vec.FV().NumPy()[free])
    assert inv.converged and 1e-12 < inv.scaled_residual <= np.sqrt(1e-8)
    # the bubbles are condensed exactly, so the condensed residual is the assembled one
    assert inv.relative_residual == pytest.approx(true, rel=1e-3)

    monkeypatch.setattr(inverse_module, "check_not_singular", lambda *args: None)
    fes_n = ngs.H1(mesh, order=1)
    un, vn = fes_n.TnT()
    singular = DDInverse(ngs.BilinearForm(ngs.grad(un) * ngs.grad(vn) * ngs.dx), method=method, parts=4)
    g = ngs.LinearForm(fes_n)
    g += (ngs.x - 0.3) * vn * ngs.dx          # not orthogonal to the constants: no solution
    g.Assemble()
    _solve(singular, g.vec)
    # bddc: a PCG breakdown; fetidp and feti met their rule, but u does not solve the equations
    assert not singular.converged and singular.relative_residual > 1.0 and singular.scaled_residual > 1.0
    if method != "bddc":
        assert singular.reason.startswith("the solution does not satisfy A u = f to the tolerance: estimated relative "
                                          "energy error") and singular.error_estimate > 1.0


def _jacobi_residual(a, fes, f, x):
    """||D^{-1/2} (f - A x)|| / ||D^{-1/2} f|| on the free dofs of the assembled a.mat, D = diag(a.mat)."""
    free = np.array(fes.FreeDofs(), dtype=bool)
    gx, ax, diag = ngs.BaseVector(fes.ndof), ngs.BaseVector(fes.ndof), ngs.BaseVector(fes.ndof)
    gx.FV().NumPy()[:] = x
    ax.data = a.mat * gx
    diag.FV().NumPy()[:] = [a.mat[i, i] for i in range(fes.ndof)]
    w = 1.0 / np.sqrt(diag.FV().NumPy()[free])
    r = (f.vec.FV().NumPy() - ax.FV().NumPy())[free] * w
    return np.linalg.norm(r) / np.linalg.norm(f.vec.FV().NumPy()[free] * w)


@pytest.mark.parametrize(("method", "scaling", "converged"), [("bddc", "diagonal", True), ("fetidp", "diagonal", False),
                                                       ("fetidp", "deluxe", True), ("feti", "diagonal", False)])
def test_coefficient_jump_is_judged_by_the_energy_error(structured_mesh, method, scaling, converged):
    """A checkerboard coefficient 1, 1e6 cut by the METIS parts, order 2, rtol 1e-8 (a structured 24 x 24 mesh,
    the same on every machine). FETI-DP (energy error 8.1e-7) and FETI (2.4e-6) read ||f - A u|| / ||f|| of
    3.3e-4 and 1.8e-3 and were once reported not converged for it: the jump inflates that residual. The
    decision is the estimated relative energy error sqrt(r^T M^-1 r / f^T u), an upper bound of the true one,
    above it by at most sqrt(cond) of the BDDC preconditioner: with the diagonal weights, not robust for jumps
    inside the parts, FETI-DP's bound (118x its error of 81 rtol) and FETI's (48x) exceed the limit 100 rtol,
    and they are reported not converged; with deluxe weights FETI-DP's bound is tight (1.0x) and within it.
    (On netgen's mesh of maxh 0.05 the same case read 5.5e-7 and 7.2e-6 on one machine, 1.08e-6 for FETI-DP on
    another: the test's mesh is structured since.)"""
    fes = ngs.H1(structured_mesh, order=2, dirichlet=".*")
    u, v = fes.TnT()
    rho = ngs.IfPos(ngs.sin(4 * ngs.pi * ngs.x) * ngs.sin(4 * ngs.pi * ngs.y), 1e6, 1.0)
    a = ngs.BilinearForm(rho * ngs.grad(u) * ngs.grad(v) * ngs.dx).Assemble()
    f = ngs.LinearForm(1 * v * ngs.dx).Assemble()
    inv = DDInverse(a, method=method, parts=16, rtol=1e-8, scaling=scaling)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        x = _solve(inv, f.vec)
    exact = ngs.GridFunction(fes)
    exact.vec.data = a.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky") * f.vec
    e = ngs.BaseVector(fes.ndof)
    e.FV().NumPy()[:] = x - exact.vec.FV().NumPy()
    energy_error = np.sqrt(ngs.InnerProduct(a.mat * e, e) / ngs.InnerProduct(a.mat * exact.vec, exact.vec))
    assert inv.converged is converged, inv.reason
    assert [issubclass(w.category, ConvergenceWarning) for w in caught] == ([] if converged else [True])
    assert energy_error <= inv.error_estimate * (1 + 1e-6) <= 500 * energy_error   # an upper bound, not a wild one
    if method != "bddc":
        assert inv.relative_residual > np.sqrt(1e-8)             # the unscaled residual is inflated by the jump
    assert inv.scaled_residual == pytest.approx(_jacobi_residual(a, fes, f, x), rel=1e-3)
    assert energy_error < (1e-5 if method == "feti" else 1e-6)
    if not converged:
        assert inv.error_estimate > inv.error_limit == 1e-6
    if scaling == "deluxe":
        assert inv.error_estimate <= 1.1 * energy_error


def test_space_on_another_mesh_is_refused():
    mesh_a = MakeStructured2DMesh(quads=False, nx=8, ny=8)
    mesh_b = MakeStructured2DMesh(quads=False, nx=8, ny=8, mapping=lambda x, y: (3 * x, y))
    u, v = ngs.H1(mesh_a, order=1, dirichlet="left").TnT()
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx)
    with pytest.raises(InputError, match=r"^fes: is on another mesh"):
        DDInverse(a, ngs.H1(mesh_b, order=1, dirichlet="left"), parts=4)


def test_messages_name_the_argument(mesh):
    fv = ngs.H1(mesh, order=1, dim=2, dirichlet=".*")
    u, v = fv.TnT()
    with pytest.raises(InputError, match=r"^fes: vector-valued H1 \(dim=2\) is not supported"):
        DDInverse(ngs.BilinearForm(ngs.InnerProduct(ngs.grad(u), ngs.grad(v)) * ngs.dx), parts=4)
    fes = ngs.H1(mesh, order=1, dirichlet=".*")
    u, v = fes.TnT()
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx)
    for seed in ("x", 1.5, True):
        with pytest.raises(InputError, match=r"^seed: must be an integer"):
            DDInverse(a, parts=4, seed=seed)
    inv = DDInverse(a, parts=4)
    z = ngs.BaseVector(fes.ndof, True)
    z[:] = 1j
    out = ngs.BaseVector(fes.ndof)
    for op in (inv, inv.preconditioner):
        with pytest.raises(InputError, match=r"^f: complex vectors are not supported"):
            out.data = op * z
