"""Checks that the element matrices ``DDInverse`` reads are the user's operator.

``DDInverse`` builds its subdomain matrices from element matrices: NGSolve's assembly of the volume
integrators on ``Discontinuous(fes)``, and ``CalcElementMatrix`` of the boundary (``ds``) integrators
(:mod:`ddsolve.dofs`). Two kinds of form gave other matrices, solved to rtol and reported converged
(a black-box review):

* a form that is not linear in the trial function (``u**3 * v * dx`` of a Newton iteration, after
  ``a.AssembleLinearization(w)``): its element "matrix" is not its operator; 4.6x off;
* a ``ds`` term with ``deformation=``: ``CalcElementMatrix`` on the undeformed element ignores it
  (NGSolve's assembly does not); 6% off. (A boundary ``SetDefinedOnElements`` mask is refused the
  same way: it cannot be read from Python.)

The checks cost 64 elements per integrator and, for ``ds`` terms, one NGSolve assembly of the
boundary terms alone (O(boundary elements)) and one product with it.
"""
from __future__ import annotations

import faulthandler
import logging
import os
import time
import warnings
from typing import Any

import numpy as np

from ..errors import InputError

__all__ = ["check_boundary_terms", "check_finite", "check_linear", "has_trial_function"]

log = logging.getLogger(__name__)

#: Elements of each integrator's region on which its linearity is checked (spread over the region).
SAMPLES = 64

#: Relative difference above which two evaluations of the same operator are not the same (rounding
#: leaves about 1e-15).
TOLERANCE = 1e-8


def _differ(y: np.ndarray, z: np.ndarray) -> float:
    """||y - z|| / max(||y||, ||z||), on vectors scaled by their largest entry first (entries above 1e154
    overflowed the norms to inf, the ratio read NaN and every check passed; a review). Non-finite entries
    read 0 here: the NaN and Inf checks of the element matrices refuse them with their own message."""
    y, z = np.asarray(y, dtype=float), np.asarray(z, dtype=float)
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(z))):
        return 0.0
    top = max(float(np.abs(y).max(initial=0.0)), float(np.abs(z).max(initial=0.0)))
    if top == 0.0:
        return 0.0
    y, z = y / top, z / top
    return float(np.linalg.norm(y - z)) / max(float(np.linalg.norm(y)), float(np.linalg.norm(z)))


#: Seconds a probe of :func:`has_trial_function` may take before it is given up (then assumed True).
PROBE_SECONDS = 30.0


def has_trial_function(integ: Any, fe: Any, trafo: Any) -> bool:
    """Whether ``integ.CalcElementMatrix`` can be called (False: a structurally zero term, ``0*u*v*dx``).

    NGSolve simplifies ``0*u*v``, ``CF(0)*u*v`` and ``0*grad(u)*grad(v)`` to a ZeroCoefficientFunction;
    its integrator has no trial function, and ``CalcElementMatrix``/``ApplyElementMatrix`` dereference the
    missing one (``SymbolicBilinearFormIntegrator::GetDimension``): a segmentation fault, not an exception
    (a review: DDInverse of ``grad(u)*grad(v)*dx + 0*u*v*dx`` killed the Python process). NGSolve's own
    assembly never calls them, and nothing on the integrator tells Python. So a forked child calls it once,
    on one element, with core dumps, the fault handler and its output off; the parent reads how it ended
    (15-35 ms with 1.6 GB resident). Where ``os.fork`` does not exist, or the child neither ends nor dies
    within :data:`PROBE_SECONDS`, True.
    """
    if not hasattr(os, "fork"):
        return True
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)      # Python >= 3.12: fork of a threaded process
        pid = os.fork()
    if pid == 0:                                                  # the child: never returns
        code = 1
        try:
            faulthandler.disable()
            import resource
            resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            integ.CalcElementMatrix(fe, trafo)
            code = 0
        finally:
            os._exit(code)
    deadline = time.monotonic() + PROBE_SECONDS
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return not os.WIFSIGNALED(status)
        if time.monotonic() > deadline:
            os.kill(pid, 9)
            os.waitpid(pid, 0)
            return True
        time.sleep(0.001)


def check_linear(a: Any, fes: Any, boundary: list) -> None:
    """Refuse an integrator that is not linear in the trial function.

    On :data:`SAMPLES` elements spread over each integrator's region (volume elements, boundary
    elements for the ``ds`` integrators ``boundary``), ``ApplyElementMatrix(x)`` (the form's operator)
    is compared with ``CalcElementMatrix() x`` (what the assembly reads) for a seeded random x. A term
    nonlinear on less than about 1/64 of its region can pass. A structurally zero term (no trial
    function, :func:`has_trial_function`) adds nothing and is skipped.

    Raises
    ------
    InputError
        ``a``, naming the integrator.
    """
    import ngsolve

    from .dofs import defined_on, element_index

    mesh = fes.mesh
    rng = np.random.default_rng(0)
    regions = {ngsolve.VOL: element_index(mesh) - 1,                 # NGSolve's 0-based region of each element
               ngsolve.BND: np.array([el.index for el in mesh.Elements(ngsolve.BND)], dtype=np.int64)}
    for k, integ in enumerate(a.integrators):
        kind = ngsolve.BND if any(integ is b for b in boundary) else ngsolve.VOL
        on = np.array(integ.GetDefinedOn(), dtype=bool)
        index = regions[kind]
        inside = np.flatnonzero([defined_on(on, int(i)) for i in range(int(index.max(initial=-1)) + 1)])
        elements = np.flatnonzero(np.isin(index, inside))
        if elements.size:
            ei = ngsolve.ElementId(kind, int(elements[0]))
            if not has_trial_function(integ, fes.GetFE(ei), mesh.GetTrafo(ei)):
                log.info("integrator %d has no trial function (a zero term such as 0*u*v*dx): skipped", k)
                continue
        # SAMPLES elements spread over the region (a term nonlinear on part of it only: IfPos(x - 0.5, 1, 0) u**3 v)
        for nr in elements[np.unique(np.linspace(0, elements.size - 1, min(SAMPLES, elements.size)).astype(int))]:
            ei = ngsolve.ElementId(kind, int(nr))
            fe, trafo = fes.GetFE(ei), mesh.GetTrafo(ei)
            x = rng.standard_normal(fe.ndof)
            try:
                K = integ.CalcElementMatrix(fe, trafo).NumPy()
                y = np.array(integ.ApplyElementMatrix(fe, ngsolve.Vector(x.tolist()), trafo))
            except Exception:    # noqa: BLE001 - no element matrix (a skeleton term): refused by a later check
                break
            if _differ(y, K @ x) > TOLERANCE:
                raise InputError("a", f"integrator {k} is not linear in the trial function (u**3, u*u, ...): "
                                      "DDInverse inverts linear forms (Newton: a form of the linearization)")


def check_finite(K: np.ndarray, terms: str, chunk: int = 1 << 20) -> None:
    """Refuse element matrices with NaN or Inf entries (``terms``: "dx" or "ds", for the message).

    A NaN coefficient gave "Factor is exactly singular" from deep inside SciPy (a review). One pass
    over ``K`` in chunks of ``chunk`` entries (no full-size temporary).
    """
    flat = K.reshape(-1)
    for start in range(0, flat.size, chunk):
        if not np.isfinite(flat[start:start + chunk]).all():
            raise InputError("a", f"the {terms} terms have NaN or Inf element matrix entries (a coefficient that "
                                  "is NaN or Inf somewhere, or overflows)")


def check_boundary_terms(fes: Any, boundary: list, Kb: np.ndarray, Tb: np.ndarray) -> None:
    """Refuse ``ds`` integrators whose element matrices are not NGSolve's assembly of them.

    ``Kb``, ``Tb`` (:func:`~ddsolve.ngsolve.dofs.boundary_element_matrices`) applied to a seeded random
    x against NGSolve's assembly of the ``boundary`` integrators alone: they differ where an option of
    the integrator acts in NGSolve's assembly loop only (``ds(..., deformation=gf)``).
    """
    import ngsolve

    from .dofs import _expected_proxy_notice

    form = ngsolve.BilinearForm(fes, check_unused=False)
    with _expected_proxy_notice():
        for integ in boundary:
            form += integ
    form.Assemble()
    x = np.random.default_rng(1).standard_normal(fes.ndof)
    y = _apply(form.mat, x)
    z = np.bincount(Tb.ravel(), weights=np.einsum("bij,bj->bi", Kb, x[Tb]).ravel(), minlength=fes.ndof)
    if _differ(y, z) > TOLERANCE:
        raise InputError("a", f"a ds term differs from NGSolve's assembly of it ({_differ(y, z):.1e} relative): "
                              "deformation= and SetDefinedOnElements are not supported on ds terms")


def _apply(mat: Any, x: np.ndarray) -> np.ndarray:
    """mat x for an NGSolve matrix and a NumPy vector."""
    xv = mat.CreateColVector()
    xv.FV().NumPy()[:] = x
    yv = mat.CreateRowVector()
    yv.data = mat * xv
    return np.array(yv.FV().NumPy())
