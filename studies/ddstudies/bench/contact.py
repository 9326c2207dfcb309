"""The contact problem (3.1) in the benchmarks: problem kind ``contact`` and its methods.

Registered here (imported by :mod:`ddstudies.bench`):

* problem ``contact``: :func:`~ddsolve.scene.contact.two_membranes` with the
  Dostal patch loads (``f: dostal``), the assembled :class:`~ddsolve.contact.ContactProblem`
  in ``context["contact"]``;
* methods ``active-set`` (active set + hybrid, Chapter 5; rtol is the
  tolerance of the PCG on (5.4) and of every hybrid face solve) and
  ``smalbe`` (SMALBE/MPRGP on the FETI-DP dual, Section 6.4; rtol is its
  epsilon), run once per rtol of the study;
* peer ``pdas``: the primal-dual active set method
  (:func:`~ddsolve.contact.solve_contact_direct`) with every face factored by
  the study's direct backend (``RunOptions.direct``, MKL PARDISO by default).
  It is also the time baseline of the contact cases (``direct_seconds``).

Errors of a contact case. The stiffness K is singular on the floating
membrane, so:

* ``algebraic_error`` = ||u - u_h||_K / ||u_h||_K with the block-diagonal
  stiffness K (``BenchProblem.A``). For vectors tied on an active set (as the
  iterates of the active set method and the reference are) this is the energy
  norm of the tied problem T^T K T, a norm; a rigid shift of Omega^2 that
  breaks the ties would be invisible to it, which ``l2_error`` catches;
* ``l2_error`` = ||u - u_h||_2 / ||u_h||_2 (the ``error_vs_direct`` of
  ``ddsolve solve --check`` for contact);
* ``lambda_error`` = ||lambda - lambda_h||_2 / ||lambda_h||_2, the contact
  multipliers against those of the reference;
* ``kkt_residual``: the largest relative KKT residual (5.5) of (u, lambda);
* ``total_error`` = ||u_{h/2} - P u||_{K_{h/2}} / ||u_{h/2}||_{K_{h/2}} against
  the PDAS solution of the 2x refined problem. P^T K_{h/2} P = K_h holds body
  by body (nested Q1 spaces, the same Dostal load), so the formula of
  :mod:`ddstudies.bench.refine` is exact. Contact is a variational inequality:
  Galerkin orthogonality does not hold, so total^2 is only approximately
  discretization^2 + algebraic^2 (the total error still levels off at the
  discretization error of u_h).

u_h (and lambda_h) is the project's own reference, the PDAS method with SciPy
SuperLU face solves (:func:`~ddsolve.contact.solve_contact_direct` with its
default factorization).
"""
from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ddsolve.contact import ContactProblem, ContactSolution, solve_contact_active_set, solve_contact_direct
from ddsolve.contact.direct import Factorize
from ddsolve.contact.smalbe_dual import solve_contact_smalbe
from ddsolve.multibody.direct import merge_matrix
from ddsolve.prepared import prepare
from ddsolve.spec import ProblemSpec

from .methods import MethodRun, RunOptions, register_method
from .peers import DEFAULT_DIRECT, direct_solver
from .problems import BenchProblem, bench_scene, register_problem

log = logging.getLogger(__name__)

#: Contact solvers of the benchmarks and of the scaling study.
CONTACT_METHODS: tuple[str, ...] = ("active-set", "smalbe", "pdas")


def backend_factorize(backend: str = DEFAULT_DIRECT, threads: int = 1) -> Factorize:
    """A ``factorize`` for :func:`~ddsolve.contact.solve_contact_direct` from a peer backend.

    Parameters
    ----------
    backend : str
        A key of :data:`ddstudies.bench.peers.DIRECT_SOLVERS` (``"mkl-pardiso"``: MKL PARDISO).
    threads : int
        Threads of the factorization and solves.

    Returns
    -------
    callable
        ``factorize(A) -> solve``.
    """
    def factorize(A: Any):
        return direct_solver(backend, A, threads=threads).solve
    return factorize


def solve_contact(method: str, problem: ContactProblem, *, rtol: float | None = None, maxiter: int = 1000,
                  direct: str = DEFAULT_DIRECT, threads: int = 1) -> ContactSolution:
    """Solve (3.1) with one of :data:`CONTACT_METHODS`.

    Parameters
    ----------
    method : {"active-set", "smalbe", "pdas"}
    problem : ContactProblem
    rtol : float, optional
        Tolerance of the iterative methods (active set: PCG on (5.4) and the
        hybrid face solves; SMALBE: epsilon); default 1e-5. Ignored by ``pdas``.
    maxiter : int
        Iteration limit of each Krylov solve (active set) or of all MPRGP steps (SMALBE).
    direct : str
        Backend of the ``pdas`` face factorizations.
    threads : int
        Threads of the ``pdas`` factorizations (the DD methods run with the
        caller's BLAS setting).

    Returns
    -------
    ContactSolution

    Raises
    ------
    ValueError
        Unknown method.
    """
    rtol = 1e-5 if rtol is None else float(rtol)
    if method == "active-set":
        return solve_contact_active_set(problem, rtol=rtol, pcg_rtol=rtol, maxiter=maxiter)
    if method == "smalbe":
        return solve_contact_smalbe(problem, eps=rtol, maxiter=maxiter)
    if method == "pdas":
        return solve_contact_direct(problem, factorize=backend_factorize(direct, threads))
    raise ValueError(f"unknown contact method {method!r} (choose from {', '.join(CONTACT_METHODS)})")


def contact_problem(spec: ProblemSpec, load_cells: int | None = None) -> BenchProblem:
    """Problem (3.1): two membranes, Omega^1 clamped, Omega^2 floating, non-penetration on Gamma_c.

    ``A`` is the block-diagonal stiffness K (the norm of the errors, see the
    module docstring). ``K``, ``rhs`` and ``T`` are the tied problem of full
    contact (every pair merged, SPD); no contact method uses them, they only
    keep the generic peers well defined. ``reference()`` is the PDAS solve
    with SuperLU; ``reference_vectors()`` then gives its multipliers.
    """
    prepared = prepare(spec, scene=bench_scene(spec, load_cells))
    sub, cp = prepared.sub, prepared.contact
    T = merge_matrix(sub, cp.gi, np.ones(cp.n_contact, dtype=bool))
    context: dict[str, Any] = {"contact": cp}

    def reference() -> np.ndarray:
        sol = solve_contact_direct(cp)
        if not sol.converged:
            raise RuntimeError(f"contact reference (PDAS + SuperLU) did not converge: {sol.reason}")
        context["reference_solution"] = sol
        return sol.u

    def reference_vectors() -> dict[str, np.ndarray]:
        if "reference_solution" not in context:
            reference()
        return {"lambda": np.asarray(context["reference_solution"].lam, dtype=float)}

    return BenchProblem(kind="contact", spec=spec, sub=sub, A=cp.K, f=cp.f, K=(T.T @ cp.K @ T).tocsr(),
                        rhs=T.T @ cp.f, T=T, reference=reference, context=context, baseline="pdas",
                        reference_vectors=reference_vectors, case_errors=contact_errors)


def contact_errors(problem: BenchProblem, run: MethodRun, reference: Any) -> dict[str, float]:
    """``l2_error``, ``lambda_error``, ``kkt_residual`` and ``n_active`` of a contact run.

    Parameters
    ----------
    problem : BenchProblem
        Built by :func:`contact_problem`.
    run : MethodRun
        With ``extra["lambda"]`` the contact multipliers, shape (n_c,).
    reference : Reference
        ``reference.vectors["lambda"]`` the reference multipliers.
    """
    cp: ContactProblem = problem.context["contact"]
    u_ref = reference.u_direct
    lam = np.asarray(run.extra.get("lambda", np.zeros(cp.n_contact)), dtype=float)
    lam_ref = reference.vectors.get("lambda")
    out = {"l2_error": float(np.linalg.norm(run.u - u_ref) / max(np.linalg.norm(u_ref), 1e-300)),
           "kkt_residual": float(cp.kkt(run.u, lam).max), "n_active": int(np.count_nonzero(lam > 0))}
    out["lambda_error"] = (float(np.linalg.norm(lam - lam_ref) / max(np.linalg.norm(lam_ref), 1e-300))
                           if lam_ref is not None else math.nan)
    return out


def _runner(method: str):
    def run(problem: BenchProblem, rtol: float | None, options: RunOptions) -> MethodRun:
        sol = solve_contact(method, problem.context["contact"], rtol=rtol, maxiter=options.maxiter,
                            direct=options.direct, threads=options.threads)
        iterations = sol.outer_iterations if method == "pdas" else sol.total_iterations
        return MethodRun(u=sol.u, converged=bool(sol.converged), iterations=int(iterations),
                         extra={"setup_seconds": float(sol.extra.get("setup_seconds", 0.0)),
                                "outer_iterations": int(sol.outer_iterations),
                                "pcg_iterations": int(sol.pcg_iterations),
                                "n_factorizations": int(sol.n_factorizations),
                                "reason": str(sol.reason), "lambda": np.asarray(sol.lam, dtype=float)})
    return run


register_problem("contact", contact_problem)
register_method("active-set", _runner("active-set"), problems=("contact",))
register_method("smalbe", _runner("smalbe"), problems=("contact",))
register_method("pdas", _runner("pdas"), problems=("contact",), iterative=False, peer=True)
