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
import resource
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from threadpoolctl import threadpool_limits

from .dd import MethodOutput, solve_bddc, solve_direct, solve_feti, solve_fetidp
from .dd.check import judged
from .errors import OutputError, brief
from .krylov import TRUE_RESIDUAL_FACTOR, attained  # noqa: F401  (TRUE_RESIDUAL_FACTOR re-exported)
from .limits import check_resources
from .options import METHODS
from .prepared import Prepared, check_decomposition, prepare, scene_from_spec  # noqa: F401  (re-exported)
from .result import SolveResult
from .spec import ProblemSpec

log = logging.getLogger(__name__)

# The chain spec -> scene -> assembly -> Substructures lives in ddsolve.prepared; this name stays importable.
build_scene = scene_from_spec


def energy_error(A, u: np.ndarray, u_ref: np.ndarray) -> float:
    """Relative energy-norm error ||u - u_ref||_A / ||u_ref||_A (l2 if u_ref has zero energy).

    ``u_ref`` is scaled by the power of two of max |u_ref|, the error u - u_ref by its own
    (max |u - u_ref|), and ``A`` by the power of two nearest its largest entry before the products,
    so the quadratic forms neither underflow nor overflow for solutions, errors or coefficients
    anywhere in the double range (the ratio is carried back exactly).
    """
    u = np.asarray(u, dtype=float)
    u_ref = np.asarray(u_ref, dtype=float)
    scale_u = float(np.max(np.abs(u_ref))) if u_ref.size else 0.0
    if scale_u == 0.0:
        return 0.0 if not np.any(u) else math.inf
    scale_u = math.ldexp(1.0, math.frexp(scale_u)[1])
    data = getattr(A, "data", None)
    scale_a = float(np.max(np.abs(data))) if data is not None and np.size(data) else 1.0
    scale_a = math.ldexp(1.0, -math.frexp(scale_a)[1]) if scale_a > 0 else 1.0
    As = A * scale_a                     # scale A before the products (A @ e underflowed at rho ~ 1e-307)
    ref_vec = u_ref / scale_u
    ref = float(ref_vec @ (As @ ref_vec))
    e = u - u_ref
    scale_e = float(np.max(np.abs(e))) if e.size else 0.0
    if scale_e == 0.0:
        return 0.0
    scale_e = math.ldexp(1.0, math.frexp(scale_e)[1])
    e = e / scale_e                      # the error gets its own power of two; the ratio carries it back
    if ref <= 0:
        return float(np.linalg.norm(e) / np.linalg.norm(ref_vec) * (scale_e / scale_u))
    return float(np.sqrt(max(float(e @ (As @ e)), 0.0) / ref) * (scale_e / scale_u))


def checked_error(A, u: np.ndarray, reference: MethodOutput) -> tuple[float | None, str]:
    """The relative energy error of ``u`` against a direct reference, or None and why it is missing.

    Returns
    -------
    error : float or None
        :func:`energy_error` when both solutions are finite and the reference solve succeeded.
    reason : str
        Empty when ``error`` is a number; otherwise why it could not be computed (the
        ``check_reason`` of the result).
    """
    kr = reference.krylov
    if kr is not None and not kr.converged:
        return None, f"direct reference failed: {kr.reason}"
    if not np.all(np.isfinite(reference.u)):
        return None, "direct reference is not finite"
    if not np.all(np.isfinite(u)):
        return None, "solution is not finite"
    error = energy_error(A, u, reference.u)
    if not math.isfinite(error):
        return None, "energy norm of the error is not finite (over/underflow)"
    return error, ""


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
        from .presets import solver_options
        spec = prep.spec
        options = solver_options(spec.preset, spec.problem, spec.method)
        out = method(prep.sub, rtol=spec.rtol, maxiter=spec.maxiter, cond=spec.cond, **options)
        return MethodRun(out, reference=lambda: solve_direct(prep.sub), extra={"preset": spec.preset})
    return run


def _poisson_direct(prep: Prepared) -> MethodRun:
    out = solve_direct(prep.sub)
    return MethodRun(out, reference=lambda: out, extra={"preset": prep.spec.preset})


def _multibody_runner(method: str) -> Runner:
    def run(prep: Prepared) -> MethodRun:
        from .multibody import GlobalInterface
        from .multibody.direct import solve_constrained_direct
        from .presets import solver_options

        spec, sub = prep.spec, prep.sub
        gi = GlobalInterface(sub)
        active = gi.contact_mask(spec.contact)
        reference = lambda: solve_constrained_direct(sub, gi, active)   # noqa: E731
        extra = {"n_active": int(active.sum()), "preset": spec.preset}
        options = solver_options(spec.preset, spec.problem, method)
        if method == "direct":
            out = reference()
            return MethodRun(out, reference=lambda: out, extra=extra)
        if method == "feti-feti":
            from .multibody.fetifeti import FetiFetiSolver
            out = FetiFetiSolver(sub, gi).solve(active, rtol=spec.rtol, maxiter=spec.maxiter, cond=spec.cond,
                                                **options)
        else:  # hybrid: PCR has no Lanczos estimate, so cond stays None (said in the log)
            from .multibody.fallback import with_s_ol_fallback
            from .multibody.hybrid import NO_COND_MESSAGE, HybridSolver
            if spec.cond:
                log.warning(NO_COND_MESSAGE)
            solver = HybridSolver(sub, gi)
            fallback = options.pop("s_ol_fallback", True)
            out = with_s_ol_fallback(lambda s_ol: solver.solve(active, rtol=spec.rtol, maxiter=spec.maxiter,
                                                               norm=spec.norm, projection=spec.projection,
                                                               s_ol=s_ol, **options), fallback)
        return MethodRun(out, reference=reference, extra=extra)
    return run


def _contact_runner(method: str) -> Runner:
    def run(prep: Prepared):
        from .contact.run import run_contact
        from .presets import solver_options
        return run_contact(method, prep, **solver_options(prep.spec.preset, "contact", method))
    return run


#: One solver registry per problem: ``SOLVERS[problem][method](prepared)``.
SOLVERS: dict[str, dict[str, Runner]] = {
    "poisson": {"fetidp": _poisson_runner(solve_fetidp), "feti": _poisson_runner(solve_feti),
                "bddc": _poisson_runner(solve_bddc), "direct": _poisson_direct},
    "multibody": {name: _multibody_runner(name) for name in METHODS["multibody"]},
    "contact": {name: _contact_runner(name) for name in METHODS["contact"]},
}


def solve(spec: ProblemSpec | dict[str, Any], *, max_memory: int | float | str | None = None) -> SolveResult:
    """Build, assemble and solve the problem described by ``spec``.

    Parameters
    ----------
    spec : ProblemSpec or dict
        A dict is validated with :meth:`ProblemSpec.from_mapping`.
    max_memory : int, float or str, optional
        Memory limit for the size check (bytes, or a size such as ``"8G"``);
        default: 90 % of the available memory (:func:`ddsolve.limits.check_resources`).

    Returns
    -------
    SolveResult
        Non-convergence is reported through ``converged=False`` and ``reason``;
        it is never raised.

    Raises
    ------
    InputError
        Invalid specification, or a problem whose estimated memory or set-up
        time exceeds the limits (refused before anything is allocated).
    """
    if not isinstance(spec, ProblemSpec):
        spec = ProblemSpec.from_mapping(spec)
    check_resources(spec, max_memory=max_memory)
    # Subdomain blocks are small: multithreaded BLAS only adds contention
    # (measured 100x slower multi-RHS solves on a loaded 2-core machine).
    with threadpool_limits(limits=1, user_api="blas"):
        return _solve(spec)


def _scalar_extras(extra: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in extra.items() if isinstance(v, (bool, int, float, str, np.number, np.bool_))}


# --- mesh report and output (unstructured scenes, timings, --output) --------------------------
def _sizes(spec: ProblemSpec) -> dict[str, int]:
    """The ``subdomains`` and ``elements`` of the result: the spec's, or (parts, 0) for unstructured meshes."""
    if spec.mesh == "unstructured":
        return {"subdomains": spec.parts, "elements": 0}
    return {"subdomains": spec.subdomains, "elements": spec.elements}


def result_bodies(spec: ProblemSpec, scene: Any) -> int:
    """The ``bodies`` of a result: the spec's (bodies per side of a structured multibody scene), or the
    mesh file's number of bodies (its materials; one for poisson)."""
    return int(scene.n_bodies) if spec.mesh_file and scene is not None else int(spec.bodies)


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MiB; ``ru_maxrss`` is in KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _mesh_report(spec: ProblemSpec, prep: Prepared, setup_seconds: float, solve_seconds: float) -> dict[str, Any]:
    """``timings`` (seconds: mesh, partition, assembly, setup, solve), ``peak_rss_mb``, ``n_primal``,
    ``mesh`` and ``parts`` (METIS parts per body; subdomains per body, subdomains^2, when structured)."""
    scene_seconds = prep.timings.get("scene", 0.0)
    assembly = prep.timings.get("assembly", 0.0)
    timings = {"mesh": float(prep.scene_timings.get("mesh", scene_seconds)),
               "partition": float(prep.scene_timings.get("partition", 0.0)),
               "assembly": float(assembly),
               "setup": float(max(setup_seconds - scene_seconds - assembly, 0.0)),
               "solve": float(solve_seconds)}
    parts = spec.parts if spec.mesh == "unstructured" else spec.subdomains ** 2
    return {"timings": timings, "peak_rss_mb": peak_rss_mb(), "n_primal": int(prep.sub.n_primal),
            "mesh": spec.mesh, "parts": int(parts)}


def _write_output(spec: ProblemSpec, prep: Prepared, u: np.ndarray | None, lam: np.ndarray | None = None,
                  result: SolveResult | None = None) -> None:
    """Write ``spec.output`` (a .vtu file for ParaView, :mod:`ddsolve.io.vtk`) if it is set.

    With ``result``, the field ``converged`` (1 or 0 on every element; like every field of the file a point
    field, written at the vertices of each cell, :func:`~ddsolve.io.vtk.write_vtu`) records its verdict, and a
    result that did not converge is written with a warning (it replaces a previous file all the same).

    A write that fails (no space, a file size limit, a name the file system refuses) raises
    :class:`~ddsolve.errors.OutputError` carrying ``result``, the existing file kept."""
    if not spec.output or u is None:
        return
    if not np.all(np.isfinite(u)) or (lam is not None and not np.all(np.isfinite(lam))):
        # a numerical breakdown: a file of NaN would replace the user's previous result for nothing
        log.warning("not writing %s: the solution is not finite (the solve broke down)", spec.output)
        return
    from .io.vtk import solution_fields, write_vtu
    nodal, cellwise = solution_fields(prep, u, lam)
    if result is not None:
        # the file replaces a previous one whatever the verdict: say which it holds (a field for ParaView)
        cellwise["converged"] = np.full(len(prep.scene.elements), float(bool(result.converged)))
        if not result.converged:
            log.warning("writing %s with the last iterate of a solve that did not converge (%s); its point "
                        "field 'converged' is 0", spec.output, result.reason)
    try:
        write_vtu(spec.output, prep.scene, nodal, cellwise)
    except OSError as exc:
        why = exc.strerror or str(exc)
        raise OutputError(f"could not write {brief(str(spec.output))}: {why} (the solve finished; an existing "
                          f"file there is kept)", result) from None
    log.info("wrote %s", spec.output)
# --- end of the mesh report block ----------------------------------------------------------------


def _solve(spec: ProblemSpec) -> SolveResult:
    prep = prepare(spec)
    t1 = time.perf_counter()
    run = SOLVERS[spec.problem][spec.method](prep)
    t_total = time.perf_counter() - t1
    identity = dict(problem=spec.problem, method=spec.method, bodies=result_bodies(spec, prep.scene),
                    **_sizes(spec), ndof=prep.sub.ndof)
    if spec.problem == "contact":
        from .contact.run import contact_result_fields
        fields = contact_result_fields(spec, prep.contact, run)
        fields["setup_seconds"] += prep.seconds
        fields["extra"]["n_templates"] = prep.local.n_templates
        fields["extra"].update(_mesh_report(spec, prep, fields["setup_seconds"], fields["solve_seconds"]))
        result = SolveResult(**identity, **fields)
        log.info("contact %s: %s", spec.method, result.reason)
        _write_output(spec, prep, result.u, run.lam, result)
        return result

    out = run.output
    extra = {**_scalar_extras(out.extra), **run.extra, "n_templates": prep.local.n_templates}
    fields: dict[str, Any] = dict(u=out.u, nlambda=out.nlambda, n_factorizations=out.n_factorizations,
                                  setup_seconds=prep.seconds + out.setup_seconds,
                                  solve_seconds=t_total - out.setup_seconds)
    if out.krylov is None:
        fields.update(converged=True, reason="direct solve", iterations=0)
    elif out.krylov.iterations == 0 and spec.method == "direct":   # a direct solve that failed (reason given)
        fields.update(converged=bool(out.krylov.converged), reason=out.krylov.reason, iterations=0)
    else:
        kr = out.krylov
        # FETI, FETI-DP, FETI-FETI, hybrid: the error of u itself (ddsolve.dd.check, ddsolve.multibody.check)
        converged, reason = judged(*attained(kr, spec.rtol), out.extra, spec.rtol, spec.method)
        fields.update(converged=converged, reason=reason, iterations=kr.iterations,
                      residuals=np.asarray(kr.residuals, dtype=float), true_residual=kr.true_residual)
        extra["restarts"] = int(getattr(kr, "restarts", 0))
        if spec.cond and kr.cond is not None:
            fields.update(cond=kr.cond, lambda_min=kr.lambda_min, lambda_max=kr.lambda_max)
    if fields["converged"] and not np.all(np.isfinite(out.u)):
        fields.update(converged=False, reason=f"non-finite solution after {fields['reason']}")
    if spec.check:
        reference = out if spec.method == "direct" else run.reference()
        error, why = checked_error(prep.sub.global_matrix(), out.u, reference)
        fields["error_vs_direct"] = error
        if why:
            extra["check_reason"] = why
    extra.update(_mesh_report(spec, prep, fields["setup_seconds"], fields["solve_seconds"]))
    result = SolveResult(**identity, **fields, extra=extra)
    log.info("%s %s: %s", spec.problem, spec.method, result.reason)
    _write_output(spec, prep, result.u, result=result)
    return result
