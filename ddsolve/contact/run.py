"""Glue between :func:`ddsolve.solve` and the contact solvers: a prepared problem in, the result fields out."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError
from ..spec import ProblemSpec
from .direct import ContactSolution, solve_contact_direct
from .problem import ContactProblem

if TYPE_CHECKING:  # pragma: no cover
    from ..prepared import Prepared

#: SMALBE diagnostics copied into the result (when the solver reports them).
SMALBE_KEYS = ("n_hessian", "n_cg", "n_expansion", "n_proportioning", "penalty", "rho_bar", "force_error",
               "polish", "polish_iterations", "acceptance")


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


def contact_result_fields(spec: ProblemSpec, problem: ContactProblem, sol: ContactSolution) -> dict[str, Any]:
    """The :class:`~ddsolve.result.SolveResult` fields of a contact solve.

    ``iterations`` is the total of the inner iterations; ``extra`` holds
    ``outer_iterations``, ``inner_iterations`` (list), ``pcg_iterations``,
    ``total_iterations``, ``n_active``, ``n_contact``, ``energy``,
    ``kkt_residual`` and its four parts (SMALBE also its counters, ``penalty``,
    ``rho_bar``, ``force_error`` = |sum(lambda) - net load| / net load, and
    ``polish`` ("accepted" / "rejected") with ``polish_iterations``, the PCG
    iterations of the FETI-FETI refinement on the active set, not in ``iterations``, and
    ``kkt_residual_unpolished``, the KKT residual of SMALBE's own iterate before any polish),
    ``preset``. With
    ``check``, ``error_vs_direct`` is the relative l2 error of u against the
    primal-dual active set reference
    (the stiffness is singular on the floating membrane, so the energy norm
    would not see a rigid shift of it) and ``lambda_error_vs_direct`` that of
    the multipliers (SMALBE also ``lambda_error_unpolished``, that of its iterate before
    any polish).
    """
    kkt = problem.kkt(sol.u, sol.lam)
    setup = float(sol.extra.get("setup_seconds", 0.0))
    extra: dict[str, Any] = {
        "outer_iterations": int(sol.outer_iterations),
        "inner_iterations": [int(k) for k in sol.inner_iterations],
        "pcg_iterations": int(sol.pcg_iterations),
        "total_iterations": int(sol.total_iterations),
        "n_active": int(np.count_nonzero(sol.active)),
        "n_contact": int(problem.n_contact),
        "energy": problem.energy(sol.u),
        **kkt.as_dict(),
        "preset": spec.preset,
    }
    extra.update({key: sol.extra[key] for key in SMALBE_KEYS if key in sol.extra})
    unpolished = "lambda_unpolished" in sol.extra
    if unpolished:
        extra["kkt_residual_unpolished"] = problem.kkt(sol.extra["u_unpolished"], sol.extra["lambda_unpolished"]).max
    fields: dict[str, Any] = dict(
        u=sol.u, converged=bool(sol.converged), reason=sol.reason, iterations=sol.total_iterations,
        nlambda=int(sol.extra.get("nlambda", problem.n_contact)), n_factorizations=int(sol.n_factorizations),
        setup_seconds=setup, solve_seconds=max(sol.seconds - setup, 0.0), extra=extra)
    if spec.check:
        ref = sol if spec.method == "direct" else solve_contact_direct(problem)
        fields["error_vs_direct"] = float(np.linalg.norm(sol.u - ref.u) / max(np.linalg.norm(ref.u), 1e-300))
        lam_scale = max(np.linalg.norm(ref.lam), 1e-300)
        extra["lambda_error_vs_direct"] = float(np.linalg.norm(sol.lam - ref.lam) / lam_scale)
        if unpolished:
            extra["lambda_error_unpolished"] = float(np.linalg.norm(sol.extra["lambda_unpolished"] - ref.lam)
                                                     / lam_scale)
    return fields
