"""Glue between :func:`ddsolve.solve` and the contact solvers: one spec in, one :class:`SolveResult` filled."""
from __future__ import annotations

import numpy as np

from ..result import SolveResult
from ..spec import ProblemSpec
from .direct import ContactSolution, solve_contact_direct
from .problem import ContactProblem


def run_contact_method(method: str, problem: ContactProblem, *, rtol: float, maxiter: int) -> ContactSolution:
    """Solve (3.1) with ``method`` in {"active-set", "smalbe", "direct"}.

    ``rtol`` is the inner (PCR, PCG) tolerance of the active set method and the
    epsilon of SMALBE's stopping rule.
    """
    if method == "direct":
        return solve_contact_direct(problem)
    if method == "active-set":
        from .active_set import solve_contact_active_set
        return solve_contact_active_set(problem, rtol=rtol, pcg_rtol=rtol, maxiter=maxiter)
    if method == "smalbe":
        from .smalbe_dual import solve_contact_smalbe
        return solve_contact_smalbe(problem, eps=rtol, maxiter=maxiter)
    raise ValueError(f"unknown contact method {method!r}")


def solve_contact_spec(spec: ProblemSpec, problem: ContactProblem, result: SolveResult) -> ContactSolution:
    """Solve the contact problem of ``spec`` and fill ``result``.

    ``result.iterations`` is the total of the inner iterations; ``extra`` gets
    ``outer_iterations``, ``inner_iterations`` (list), ``pcg_iterations``,
    ``total_iterations``, ``n_active``, ``n_contact``, ``energy``,
    ``kkt_residual`` and its four parts (SMALBE also its counters, ``penalty``,
    ``rho_bar``, ``force_error`` = |sum(lambda) - net load| / net load, and
    ``polish`` ("accepted" / "rejected") with ``polish_iterations``, the PCG
    iterations of the FETI-FETI refinement on the active set, not in ``iterations``). With
    ``check``, ``error_vs_direct`` is the relative l2 error of u against the
    primal-dual active set reference
    (the stiffness is singular on the floating membrane, so the energy norm
    would not see a rigid shift of it) and ``lambda_error_vs_direct`` that of
    the multipliers.
    """
    sol = run_contact_method(spec.method, problem, rtol=float(spec.rtol), maxiter=int(spec.maxiter))
    kkt = problem.kkt(sol.u, sol.lam)
    result.u = sol.u
    result.converged, result.reason = bool(sol.converged), sol.reason
    result.iterations = sol.total_iterations
    result.nlambda = int(sol.extra.get("nlambda", problem.n_contact))
    result.n_factorizations = int(sol.n_factorizations)
    setup = float(sol.extra.get("setup_seconds", 0.0))
    result.setup_seconds = setup
    result.solve_seconds = max(sol.seconds - setup, 0.0)
    result.extra.update({
        "outer_iterations": int(sol.outer_iterations),
        "inner_iterations": [int(k) for k in sol.inner_iterations],
        "pcg_iterations": int(sol.pcg_iterations),
        "total_iterations": int(sol.total_iterations),
        "n_active": int(np.count_nonzero(sol.active)),
        "n_contact": int(problem.n_contact),
        "energy": problem.energy(sol.u),
        **kkt.as_dict(),
    })
    for key in ("n_hessian", "n_cg", "n_expansion", "n_proportioning", "penalty", "rho_bar", "force_error",
                "polish", "polish_iterations"):
        if key in sol.extra:
            result.extra[key] = sol.extra[key]
    if spec.check:
        ref = sol if spec.method == "direct" else solve_contact_direct(problem)
        result.error_vs_direct = float(np.linalg.norm(sol.u - ref.u) / max(np.linalg.norm(ref.u), 1e-300))
        result.extra["lambda_error_vs_direct"] = float(
            np.linalg.norm(sol.lam - ref.lam) / max(np.linalg.norm(ref.lam), 1e-300))
    return sol
