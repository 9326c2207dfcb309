"""Glue between :func:`ddsolve.solve` and the contact solvers: a prepared problem in, the result fields out."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import math

import numpy as np

from ..errors import InputError
from ..spec import ProblemSpec
from .direct import ContactSolution, solve_contact_direct
from .problem import (KKT_ACCEPT_CEILING, KKT_ACCEPT_FACTOR, KKT_ACCEPT_FLOOR,  # noqa: F401  (re-exported)
                      ContactProblem, KKTResiduals, kkt_verdict)

if TYPE_CHECKING:  # pragma: no cover
    from ..prepared import Prepared

#: SMALBE diagnostics copied into the result (when the solver reports them).
SMALBE_KEYS = ("n_hessian", "n_cg", "n_expansion", "n_proportioning", "penalty", "rho_bar", "force_error",
               "polish", "polish_iterations", "polish_lambda_change", "acceptance", "verify", "verify_iterations",
               "verify_lambda_change")


def run_contact_method(method: str, problem: ContactProblem, *, rtol: float, maxiter: int,
                       **options: Any) -> ContactSolution:
    """Solve (3.1) with ``method`` in {"active-set", "smalbe", "direct"}.

    ``rtol`` is the inner (PCR, PCG) tolerance of the active set method and the
    epsilon of SMALBE's stopping rule. ``options`` are further keywords of the
    solver (e.g. those of a preset, :func:`ddsolve.presets.solver_options`).
    """
    if method == "direct":
        return solve_contact_direct(problem, **options)
    if method not in ("active-set", "smalbe"):
        raise ValueError(f"unknown contact method {method!r}")
    try:
        if method == "active-set":
            from .active_set import solve_contact_active_set
            return solve_contact_active_set(problem, rtol=rtol, pcg_rtol=rtol, maxiter=maxiter, **options)
        from .smalbe_dual import solve_contact_smalbe
        return solve_contact_smalbe(problem, eps=rtol, maxiter=maxiter, **options)
    except InputError:
        raise
    except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        # non-finite values (a solution beyond the double range) reached a factorization or a
        # finiteness check of scipy: a numerical breakdown, reported, never raised
        return ContactSolution(u=np.full(problem.ndof, np.nan), lam=np.full(problem.n_contact, np.nan),
                               active=np.zeros(problem.n_contact, dtype=bool), converged=False,
                               reason=f"numerical breakdown in {method}: {type(exc).__name__}: {exc}")


def run_contact(method: str, prep: "Prepared", **options: Any) -> ContactSolution:
    """Solve the contact problem of a prepared spec with ``method`` (``options``: solver keywords)."""
    return run_contact_method(method, prep.contact, rtol=float(prep.spec.rtol), maxiter=int(prep.spec.maxiter),
                              **options)


@dataclass(frozen=True)
class ContactMeasures:
    """What the result of a contact solve reports about its (u, lambda): the KKT residuals (5.5) and J(u).

    Computed from the assembled problem (:meth:`ContactProblem.kkt`, :meth:`ContactProblem.energy`)
    in serial, from the ranks' subdomains under mpiexec (:func:`ddsolve.parallel.kkt.distributed_kkt`).

    Attributes
    ----------
    kkt : KKTResiduals
    energy : float
        1/2 u^T K u - f^T u.
    n_contact : int
        Number of contact pairs n_c.
    weighted_feasibility : float or None
        The penetration weighted by the stiffness (:meth:`ContactProblem.weighted_feasibility`).
    """

    kkt: KKTResiduals
    energy: float
    n_contact: int
    weighted_feasibility: float | None = None

    @classmethod
    def of(cls, problem: ContactProblem, u: np.ndarray, lam: np.ndarray,
           kkt: KKTResiduals | None = None, weighted: float | None = None) -> ContactMeasures:
        """From the assembled problem (serial); ``kkt``, ``weighted``: those of (u, lam) if already computed."""
        return cls(kkt=problem.kkt(u, lam) if kkt is None else kkt, energy=problem.energy(u),
                   n_contact=int(problem.n_contact),
                   weighted_feasibility=problem.weighted_feasibility(u) if weighted is None else weighted)


def contact_result_fields(spec: ProblemSpec, problem: ContactProblem, sol: ContactSolution) -> dict[str, Any]:
    """The :class:`~ddsolve.result.SolveResult` fields of a contact solve (serial: the assembled problem).

    :func:`contact_fields` of the measures of ``problem`` (also ``kkt_residual_unpolished`` of
    SMALBE), then, with ``check``, :func:`check_fields` against the direct reference.
    """
    unpolished = None
    if "lambda_unpolished" in sol.extra:
        unpolished = problem.kkt(sol.extra["u_unpolished"], sol.extra["lambda_unpolished"]).max
    measures = ContactMeasures.of(problem, sol.u, sol.lam, sol.kkt, sol.extra.get("kkt_weighted_feasibility"))
    fields = contact_fields(spec, sol, measures, kkt_unpolished=unpolished)
    if spec.check:
        check_fields(spec, problem, sol, fields)
    return fields


def contact_fields(spec: ProblemSpec, sol: ContactSolution, measures: ContactMeasures, *,
                   kkt_unpolished: float | None = None) -> dict[str, Any]:
    """The :class:`~ddsolve.result.SolveResult` fields of a contact solve, from its KKT residuals and energy.

    The one definition of the fields, serial and distributed. ``iterations`` is the total of the
    inner iterations; ``extra`` holds
    ``outer_iterations``, ``inner_iterations`` (list), ``pcg_iterations``,
    ``total_iterations``, ``n_active``, ``n_contact``, ``energy``,
    ``kkt_residual`` and its four parts (SMALBE also its counters, ``penalty``,
    ``rho_bar``, ``force_error`` = |sum(lambda) - net load| / net load, and
    ``polish`` ("accepted" / "rejected") with ``polish_iterations``, the PCG
    iterations of the FETI-FETI refinement on the active set, not in ``iterations``, and
    ``kkt_residual_unpolished`` (given), the KKT residual of SMALBE's own iterate before any polish;
    without a polish ``verify``, ``verify_iterations`` and ``verify_lambda_change``: the check of a
    converged SMALBE lambda by the equality solve on its active set),
    ``preset``, ``kkt_weighted_feasibility`` (the penetration weighted by the stiffness). The result of the
    active set method or SMALBE is accepted (``converged``) only if its KKT residual and
    ``kkt_weighted_feasibility`` are at most min(max(KKT_ACCEPT_FACTOR rtol, KKT_ACCEPT_FLOOR), KKT_ACCEPT_CEILING).

    Parameters
    ----------
    spec : ProblemSpec
    sol : ContactSolution
    measures : ContactMeasures
        KKT residuals (5.5) and energy of (``sol.u``, ``sol.lam``), n_c.
    kkt_unpolished : float, optional
        SMALBE: the KKT residual of its iterate before the polish.
    """
    kkt = measures.kkt
    setup = float(sol.extra.get("setup_seconds", 0.0))
    extra: dict[str, Any] = {
        "outer_iterations": int(sol.outer_iterations),
        "inner_iterations": [int(k) for k in sol.inner_iterations],
        "pcg_iterations": int(sol.pcg_iterations),
        "total_iterations": int(sol.total_iterations),
        "n_active": int(np.count_nonzero(sol.active)),
        "n_contact": int(measures.n_contact),
        "energy": measures.energy,
        **kkt.as_dict(),
        "preset": spec.preset,
    }
    if measures.weighted_feasibility is not None:
        extra["kkt_weighted_feasibility"] = measures.weighted_feasibility
    extra.update({key: sol.extra[key] for key in SMALBE_KEYS if key in sol.extra})
    if kkt_unpolished is not None:
        extra["kkt_residual_unpolished"] = kkt_unpolished
    converged, reason = bool(sol.converged), sol.reason
    if spec.method in ("active-set", "smalbe"):     # serial: already judged by the solver; MPI: judged here
        converged, reason = kkt_verdict(converged, reason, kkt.max, spec.rtol, measures.weighted_feasibility)
    return dict(
        u=sol.u, converged=converged, reason=reason, iterations=sol.total_iterations,
        nlambda=int(sol.extra.get("nlambda", measures.n_contact)), n_factorizations=int(sol.n_factorizations),
        setup_seconds=setup, solve_seconds=max(sol.seconds - setup, 0.0), extra=extra)


def _relative_error(x: np.ndarray, ref: np.ndarray) -> float | None:
    """||x - ref|| / ||ref||, on both divided by max |ref| (a load of 1e-300 underflowed the norms to 0 and
    read 0.0; one of 1e300 overflowed them); 0 for ref = x = 0, None if either is not finite."""
    x, ref = np.asarray(x, dtype=float), np.asarray(ref, dtype=float)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(ref))):
        return None
    scale = float(np.max(np.abs(ref), initial=0.0))
    if scale == 0.0:
        return 0.0 if not np.any(x) else math.inf
    return float(np.linalg.norm(x / scale - ref / scale) / np.linalg.norm(ref / scale))


def check_fields(spec: ProblemSpec, problem: ContactProblem, sol: ContactSolution, fields: dict[str, Any]) -> None:
    """Add the ``check`` fields to ``fields`` (in place): errors against the direct reference.

    ``error_vs_direct`` is the relative l2 error of u against the
    primal-dual active set reference
    (the stiffness is singular on the floating membrane, so the energy norm
    would not see a rigid shift of it) and ``extra["lambda_error_vs_direct"]`` that of
    the multipliers (SMALBE also ``lambda_error_unpolished``, that of its iterate before
    any polish).
    """
    extra = fields["extra"]
    ref = sol if spec.method == "direct" else solve_contact_direct(problem)
    if not ref.converged and spec.method != "direct":
        # the errors below are then against a failed reference (a review: --check at checkerboard 1e10
        # printed errors of 2e-3 against a cycling reference and said nothing)
        extra["check_reason"] = f"the direct reference did not converge ({ref.reason}); the errors are against it"
    fields["error_vs_direct"] = _relative_error(sol.u, ref.u)
    extra["lambda_error_vs_direct"] = _relative_error(sol.lam, ref.lam)
    if "lambda_unpolished" in sol.extra:
        extra["lambda_error_unpolished"] = _relative_error(sol.extra["lambda_unpolished"], ref.lam)
