"""One call from a :class:`~ddsolve.spec.ProblemSpec` to a :class:`~ddsolve.result.SolveResult`."""
from __future__ import annotations

import logging
import math
import time
from typing import Any, Callable

import numpy as np
from threadpoolctl import threadpool_limits

from .dd import MethodOutput, Substructures, solve_bddc, solve_direct, solve_feti, solve_fetidp
from .krylov import KrylovResult
from .multibody import GlobalInterface
from .multibody.direct import solve_constrained_direct
from .multibody.fetifeti import FetiFetiSolver
from .result import SolveResult
from .prepared import check_decomposition, prepare, scene_from_spec  # noqa: F401  (re-exported)
from .spec import ProblemSpec

log = logging.getLogger(__name__)

_ITERATIVE: dict[str, Callable[..., MethodOutput]] = {
    "feti": solve_feti,
    "fetidp": solve_fetidp,
    "bddc": solve_bddc,
}


def _multibody_solver(method: str, sub: Substructures, gi: GlobalInterface):
    """The multibody solver object for ``method`` (factorizations happen here)."""
    if method == "feti-feti":
        return FetiFetiSolver(sub, gi)
    from .multibody.hybrid import HybridSolver
    return HybridSolver(sub, gi)


# The chain spec -> scene -> assembly -> Substructures lives in ddsolve.prepare; these names stay importable.
build_scene = scene_from_spec


#: A Krylov solve counts as converged only if the residual recomputed from its
#: final iterate is within this factor of the tolerance rtol ||r_0||.
TRUE_RESIDUAL_FACTOR = 10.0


def attained(kr: KrylovResult, rtol: float) -> tuple[bool, str]:
    """Whether a converged Krylov solve also meets ``rtol`` by its recomputed residual.

    At a tolerance below the attainable accuracy (round-off, e.g. ``rtol =
    1e-20``) the recursively updated residual of PCG keeps decreasing while the
    true residual ``||P (b - A x)||`` stagnates; the solve must then not report
    convergence.

    Returns
    -------
    ok : bool
        False if ``kr.converged`` but ``kr.true_residual > TRUE_RESIDUAL_FACTOR
        rtol ||r_0||``.
    reason : str
        ``kr.reason``, extended by why the solve was not accepted.
    """
    if not kr.converged or kr.true_residual is None or kr.residuals.size == 0:
        return kr.converged, kr.reason
    r0 = float(kr.residuals[0])
    if kr.true_residual <= TRUE_RESIDUAL_FACTOR * rtol * r0:
        return True, kr.reason
    rel = kr.true_residual / r0 if r0 > 0 else math.inf
    rec = float(kr.residuals[-1]) / r0 if r0 > 0 else math.inf
    return False, (f"tolerance not attained: recomputed ||r||/||r0|| = {rel:.1e} > "
                   f"{TRUE_RESIDUAL_FACTOR:g} rtol = {TRUE_RESIDUAL_FACTOR * rtol:.1e} although the recursive "
                   f"residual reached {rec:.1e} (rtol below the attainable accuracy)")


def energy_error(A, u: np.ndarray, u_ref: np.ndarray) -> float:
    """Relative energy-norm error ||u - u_ref||_A / ||u_ref||_A (l2 if u_ref has zero energy)."""
    e = u - u_ref
    ref = float(u_ref @ (A @ u_ref))
    if ref <= 0:
        return float(np.linalg.norm(e) / max(np.linalg.norm(u_ref), 1e-300))
    return float(np.sqrt(max(float(e @ (A @ e)), 0.0) / ref))


def solve(spec: ProblemSpec | dict[str, Any]) -> SolveResult:
    """Build, assemble and solve the problem described by ``spec``.

    Parameters
    ----------
    spec : ProblemSpec or dict
        A dict is validated with :meth:`ProblemSpec.from_mapping`.

    Returns
    -------
    SolveResult
        Non-convergence is reported through ``converged=False`` and ``reason``;
        it is never raised.

    Raises
    ------
    InputError
        Invalid specification.
    """
    if not isinstance(spec, ProblemSpec):
        spec = ProblemSpec.from_mapping(spec)
    # Subdomain blocks are small: multithreaded BLAS only adds contention
    # (measured 100x slower multi-RHS solves on a loaded 2-core machine).
    with threadpool_limits(limits=1, user_api="blas"):
        return _solve(spec)


def _solve(spec: ProblemSpec) -> SolveResult:
    prepared = prepare(spec)
    local, sub = prepared.local, prepared.sub
    t_assembly = prepared.seconds

    result = SolveResult(problem=spec.problem, method=spec.method, bodies=spec.bodies,
                         subdomains=spec.subdomains, elements=spec.elements, ndof=sub.ndof)
    t1 = time.perf_counter()
    if spec.problem == "contact":
        from .contact.run import solve_contact_spec
        solve_contact_spec(spec, prepared.contact, result)
        result.setup_seconds += t_assembly
        result.extra["n_templates"] = local.n_templates
        log.info("contact %s: %s", spec.method, result.reason)
        return result
    reference: Callable[[], MethodOutput] = lambda: solve_direct(sub)   # noqa: E731
    if spec.problem == "multibody":
        gi = GlobalInterface(sub)
        active = gi.contact_mask(spec.contact)
        reference = lambda: solve_constrained_direct(sub, gi, active)   # noqa: E731
        if spec.method == "direct":
            out = reference()
        else:
            # PCR (hybrid) has no Lanczos estimate: cond stays None there.
            options = ({"cond": spec.cond} if spec.method == "feti-feti"
                       else {"norm": spec.norm, "projection": spec.projection})
            out = _multibody_solver(spec.method, sub, gi).solve(active, rtol=spec.rtol, maxiter=spec.maxiter,
                                                                **options)
        result.extra["n_active"] = int(active.sum())
    elif spec.method == "direct":
        out = reference()
    else:
        out = _ITERATIVE[spec.method](sub, rtol=spec.rtol, maxiter=spec.maxiter, cond=spec.cond)
    t_total = time.perf_counter() - t1

    result.u = out.u
    result.nlambda = out.nlambda
    result.n_factorizations = out.n_factorizations
    result.setup_seconds = t_assembly + out.setup_seconds
    result.solve_seconds = t_total - out.setup_seconds
    result.extra.update({k: v for k, v in out.extra.items()
                         if isinstance(v, (bool, int, float, str, np.number, np.bool_))})
    result.extra["n_templates"] = local.n_templates
    if out.krylov is None:
        result.converged, result.reason, result.iterations = True, "direct solve", 0
    else:
        kr = out.krylov
        (result.converged, result.reason), result.iterations = attained(kr, spec.rtol), kr.iterations
        result.residuals = np.asarray(kr.residuals, dtype=float)
        result.true_residual = kr.true_residual
        if spec.cond and kr.cond is not None:
            result.cond, result.lambda_min, result.lambda_max = kr.cond, kr.lambda_min, kr.lambda_max
    if spec.check:
        ref = out if spec.method == "direct" else reference()
        result.error_vs_direct = energy_error(sub.global_matrix(), out.u, ref.u)
    log.info("%s %s: %s", spec.problem, spec.method, result.reason)
    return result
