"""One call from a :class:`~ddsolve.spec.ProblemSpec` to a :class:`~ddsolve.result.SolveResult`.

:func:`solve` is :func:`ddsolve.prepared.prepare` (scene, assembly,
substructures) followed by the method of the spec, looked up in
:data:`SOLVERS` (one registry per problem). Each registered runner returns a
:class:`MethodRun`; the :class:`SolveResult` is built from it once, at the end,
and never modified afterwards.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from threadpoolctl import threadpool_limits

from .dd import MethodOutput, solve_bddc, solve_direct, solve_feti, solve_fetidp
from .krylov import KrylovResult
from .options import METHODS
from .prepared import Prepared, check_decomposition, prepare, scene_from_spec  # noqa: F401  (re-exported)
from .result import SolveResult
from .spec import ProblemSpec

log = logging.getLogger(__name__)

# The chain spec -> scene -> assembly -> Substructures lives in ddsolve.prepared; this name stays importable.
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


@dataclass(frozen=True)
class MethodRun:
    """What a registered runner hands back to :func:`solve`.

    Attributes
    ----------
    output : MethodOutput
        Solution, Krylov result, multiplier count, factorizations, setup time, extras.
    reference : callable
        Computes the direct solution of the same discrete problem (for ``check``).
    extra : dict
        Scene-level diagnostics added to the result (e.g. ``n_active``).
    """

    output: MethodOutput
    reference: Callable[[], MethodOutput]
    extra: dict[str, Any] = field(default_factory=dict)


Runner = Callable[[Prepared], Any]


def _poisson_runner(method: Callable[..., MethodOutput]) -> Runner:
    def run(prep: Prepared) -> MethodRun:
        spec = prep.spec
        out = method(prep.sub, rtol=spec.rtol, maxiter=spec.maxiter, cond=spec.cond)
        return MethodRun(out, reference=lambda: solve_direct(prep.sub))
    return run


def _poisson_direct(prep: Prepared) -> MethodRun:
    out = solve_direct(prep.sub)
    return MethodRun(out, reference=lambda: out)


def _multibody_runner(method: str) -> Runner:
    def run(prep: Prepared) -> MethodRun:
        from .multibody import GlobalInterface
        from .multibody.direct import solve_constrained_direct

        spec, sub = prep.spec, prep.sub
        gi = GlobalInterface(sub)
        active = gi.contact_mask(spec.contact)
        reference = lambda: solve_constrained_direct(sub, gi, active)   # noqa: E731
        if method == "direct":
            out = reference()
            return MethodRun(out, reference=lambda: out, extra={"n_active": int(active.sum())})
        if method == "feti-feti":
            from .multibody.fetifeti import FetiFetiSolver
            out = FetiFetiSolver(sub, gi).solve(active, rtol=spec.rtol, maxiter=spec.maxiter, cond=spec.cond)
        else:  # hybrid: PCR has no Lanczos estimate, so cond stays None
            from .multibody.hybrid import HybridSolver
            out = HybridSolver(sub, gi).solve(active, rtol=spec.rtol, maxiter=spec.maxiter,
                                              norm=spec.norm, projection=spec.projection)
        return MethodRun(out, reference=reference, extra={"n_active": int(active.sum())})
    return run


def _contact_runner(method: str) -> Runner:
    def run(prep: Prepared):
        from .contact.run import run_contact
        return run_contact(method, prep)
    return run


#: One solver registry per problem: ``SOLVERS[problem][method](prepared)``.
SOLVERS: dict[str, dict[str, Runner]] = {
    "poisson": {"fetidp": _poisson_runner(solve_fetidp), "feti": _poisson_runner(solve_feti),
                "bddc": _poisson_runner(solve_bddc), "direct": _poisson_direct},
    "multibody": {name: _multibody_runner(name) for name in METHODS["multibody"]},
    "contact": {name: _contact_runner(name) for name in METHODS["contact"]},
}


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


def _scalar_extras(extra: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in extra.items() if isinstance(v, (bool, int, float, str, np.number, np.bool_))}


def _solve(spec: ProblemSpec) -> SolveResult:
    prep = prepare(spec)
    t1 = time.perf_counter()
    run = SOLVERS[spec.problem][spec.method](prep)
    t_total = time.perf_counter() - t1
    identity = dict(problem=spec.problem, method=spec.method, bodies=spec.bodies, subdomains=spec.subdomains,
                    elements=spec.elements, ndof=prep.sub.ndof)
    if spec.problem == "contact":
        from .contact.run import contact_result_fields
        fields = contact_result_fields(spec, prep.contact, run)
        fields["setup_seconds"] += prep.seconds
        fields["extra"]["n_templates"] = prep.local.n_templates
        result = SolveResult(**identity, **fields)
        log.info("contact %s: %s", spec.method, result.reason)
        return result

    out = run.output
    extra = {**_scalar_extras(out.extra), **run.extra, "n_templates": prep.local.n_templates}
    fields: dict[str, Any] = dict(u=out.u, nlambda=out.nlambda, n_factorizations=out.n_factorizations,
                                  setup_seconds=prep.seconds + out.setup_seconds,
                                  solve_seconds=t_total - out.setup_seconds)
    if out.krylov is None:
        fields.update(converged=True, reason="direct solve", iterations=0)
    else:
        kr = out.krylov
        converged, reason = attained(kr, spec.rtol)
        fields.update(converged=converged, reason=reason, iterations=kr.iterations,
                      residuals=np.asarray(kr.residuals, dtype=float), true_residual=kr.true_residual)
        extra["restarts"] = int(getattr(kr, "restarts", 0))
        if spec.cond and kr.cond is not None:
            fields.update(cond=kr.cond, lambda_min=kr.lambda_min, lambda_max=kr.lambda_max)
    if spec.check:
        reference = out if spec.method == "direct" else run.reference()
        fields["error_vs_direct"] = energy_error(prep.sub.global_matrix(), out.u, reference.u)
    result = SolveResult(**identity, **fields, extra=extra)
    log.info("%s %s: %s", spec.problem, spec.method, result.reason)
    return result
