"""Regressions from the eighth black-box review of ddsolve.ngsolve (2026-11-27).

* A form with a structurally zero term (``0*u*v*dx``) killed the Python process (a segmentation fault in
  NGSolve's ``CalcElementMatrix`` of an integrator without trial function); it is now skipped.
* ``inv.H * z`` (NGSolve's ``ConjTrans``) read the real vectors as complex numbers: garbage, not an error.
* A NaN or Inf coefficient in a ``ds`` term was dropped and the solve reported converged; in a ``dx``
  term it gave "Factor is exactly singular" from deep inside SciPy. Both are an ``InputError`` on ``a``.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.geom2d import unit_square

from ddsolve.errors import InputError
from ddsolve.ngsolve import DDInverse
from ddsolve.ngsolve.consistency import has_trial_function
from test_ddinverse_review7 import _relative_error      # against NGSolve's sparse Cholesky


@pytest.fixture(scope="module")
def mesh():
    return ngs.Mesh(unit_square.GenerateMesh(maxh=0.1))


def _zero_terms(u, v):
    return {"0*u*v*dx": 0 * u * v * ngs.dx, "0.0*u*v*ds": 0.0 * u * v * ngs.ds,
            "CF(0)*u*v*dx": ngs.CF(0) * u * v * ngs.dx, "0*grad*grad*dx": 0 * ngs.grad(u) * ngs.grad(v) * ngs.dx}


@pytest.mark.parametrize("order", [1, 3])
@pytest.mark.parametrize("term", ["0*u*v*dx", "0.0*u*v*ds", "CF(0)*u*v*dx", "0*grad*grad*dx"])
def test_a_zero_term_is_skipped_not_a_crash(mesh, order, term):
    fes = ngs.H1(mesh, order=order, dirichlet="left")
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += ngs.grad(u) * ngs.grad(v) * ngs.dx + _zero_terms(u, v)[term]
    inv = DDInverse(a, parts=6, rtol=1e-10)
    assert _relative_error(a, fes, inv) < 1e-8
    assert inv.converged


def test_has_trial_function_tells_a_zero_integrator(mesh):
    fes = ngs.H1(mesh, order=2)
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += ngs.grad(u) * ngs.grad(v) * ngs.dx + 0 * u * v * ngs.dx + (u - u) * v * ngs.dx
    ei = ngs.ElementId(ngs.VOL, 0)
    fe, trafo = fes.GetFE(ei), mesh.GetTrafo(ei)
    # (u - u) * v is not simplified by NGSolve: it has trial functions, and a zero element matrix
    assert [has_trial_function(integ, fe, trafo) for integ in a.integrators] == [True, False, True]


def _apply(matrix, vec):
    out = vec.CreateVector()
    out.data = matrix * vec
    return out.FV().NumPy().copy()


def test_H_is_the_operator_itself(mesh):
    fes = ngs.H1(mesh, order=2, dirichlet="left")
    u, v = fes.TnT()
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx + u * v * ngs.dx)
    inv = DDInverse(a, parts=6, rtol=1e-10)
    z = ngs.LinearForm(ngs.sin(3 * ngs.x) * v * ngs.dx).Assemble().vec
    for op in (inv, inv.preconditioner):
        y, y_h, y_t = _apply(op, z), _apply(op.H, z), _apply(op.T, z)
        assert np.linalg.norm(y_h - y) <= 1e-14 * np.linalg.norm(y)
        assert np.linalg.norm(y_t - y) <= 1e-14 * np.linalg.norm(y)
        z2 = z.CreateVector()
        z2.data = 2 * z
        assert np.linalg.norm(_apply(op.H, z2) - 2 * y_h) <= 1e-12 * np.linalg.norm(y_h)


@pytest.mark.parametrize("case", ["nan ds", "inf ds", "nan dx", "nan in part of dx", "nan in a GridFunction", "inf dx"])
def test_a_non_finite_coefficient_is_refused(mesh, case):
    fes = ngs.H1(mesh, order=2, dirichlet="left")
    u, v = fes.TnT()
    g = ngs.GridFunction(ngs.H1(mesh, order=1))
    g.Set(1)
    g.vec[3] = float("nan")
    extra = {"nan ds": float("nan") * u * v * ngs.ds("right"), "inf ds": float("inf") * u * v * ngs.ds,
             "nan dx": float("nan") * u * v * ngs.dx,
             "nan in part of dx": ngs.IfPos(ngs.x - 0.5, float("nan"), 1) * u * v * ngs.dx,
             "nan in a GridFunction": g * u * v * ngs.dx, "inf dx": float("inf") * u * v * ngs.dx}[case]
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx + extra)
    with pytest.raises(InputError, match="NaN or Inf") as err:
        DDInverse(a, parts=6)
    assert err.value.field == "a"


def test_a_zero_form_is_refused_without_a_runtime_warning(mesh):
    fes = ngs.H1(mesh, order=2, dirichlet="left")
    u, v = fes.TnT()
    a = ngs.BilinearForm(ngs.Parameter(0) * ngs.grad(u) * ngs.grad(v) * ngs.dx)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match="not positive definite") as err:
            DDInverse(a, parts=6)
    assert err.value.field == "a"
