"""One work-precision case: run a method at one tolerance and measure time, errors and memory.

:func:`compute_reference` solves a problem and its 2x refinement directly
once (the reference of all cases of that problem); :func:`run_case` runs one
method at one rtol on the same problem and returns a :class:`CaseRecord`:

* ``wall_seconds``: the method's setup and solve (everything its runner
  does; the shared NGSolve assembly and :class:`~ddsolve.dd.Substructures`
  are excluded), best of ``repeats`` runs;
* ``direct_seconds``: the direct solve of the same problem (factorization
  and solve of the reduced system with the configured backend), timed in the
  same process right after the runs, best of ``repeats``; ``time_ratio`` =
  wall_seconds / direct_seconds is robust to slow drifts of the load of a
  shared machine;
* ``cpu_seconds``, ``direct_cpu_seconds``, ``cpu_ratio``: the same with the
  process CPU time (best of ``repeats``), which other processes on the
  machine hardly perturb (with ``threads`` = 1 it is the single-core time);
* ``algebraic_error``: ||u - u_h||_A / ||u_h||_A with u_h the project's own
  direct solve (:func:`ddsolve.api.energy_error`);
* ``total_error``: ||u_{h/2} - P u||_{A_{h/2}} / ||u_{h/2}||_{A_{h/2}}
  against the 2x refined solution (:mod:`ddstudies.bench.refine`);
* ``mem_mb`` / ``peak_rss_mb``: see :mod:`ddstudies.bench.memory`;
* problem-specific measures of :attr:`BenchProblem.case_errors` (contact:
  ``l2_error``, ``lambda_error``, ``kkt_residual``; :mod:`ddstudies.bench.contact`).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from ddsolve.api import energy_error
from ddsolve.spec import ProblemSpec

from .memory import current_rss_mb, peak_rss_mb
from .methods import MethodRun, RunOptions, get_method, run_direct
from .peers import direct_solver
from .problems import BenchProblem, build_problem
from .refine import FineReference, prolongation, refined_spec

log = logging.getLogger(__name__)


@dataclass
class Reference:
    """Reference solutions of one benchmark problem.

    Attributes
    ----------
    u_direct : ndarray, shape (ndof,)
        Direct solution u_h of the problem (algebraic reference).
    fine : FineReference
        Energy and coarse vector of the 2x refined solution (total error).
    discretization_error : float
        Total error of u_h itself.
    info : dict
        Sizes, timings and the Galerkin check ``galerkin_defect`` =
        max |P^T A_{h/2} P - A_h| / max |A_h| (round-off for nested meshes).
    vectors : dict of str to ndarray
        Further vectors of the reference solve
        (:attr:`BenchProblem.reference_vectors`, e.g. ``lambda`` for contact).
    """

    u_direct: np.ndarray
    fine: FineReference
    discretization_error: float
    info: dict[str, Any] = field(default_factory=dict)
    vectors: dict[str, np.ndarray] = field(default_factory=dict)


def compute_reference(problem: BenchProblem, factor: int = 2) -> Reference:
    """Direct solutions of ``problem`` and of its ``factor`` x refined version (factor 2)."""
    if factor != 2:
        raise ValueError("the prolongation supports one uniform refinement (factor 2)")
    spec = problem.spec
    t0 = time.perf_counter()
    u_h = problem.reference()
    vectors = dict(problem.reference_vectors()) if problem.reference_vectors is not None else {}
    fine = build_problem(refined_spec(spec, factor), load_cells=problem.load_cells)
    u_fine = fine.reference()
    P = prolongation(problem.sub.scene, problem.sub.dof_of_node, fine.sub.scene, fine.sub.dof_of_node)
    scale = float(abs(problem.A).max())
    defect = float(abs(P.T @ fine.A @ P - problem.A).max()) / scale if scale > 0 else 0.0
    ref = FineReference.from_fine(fine.A, u_fine, P)
    disc = ref.total_error(problem.A, u_h)
    log.info("%s reference: ndof %d, fine ndof %d, discretization error %.3e, Galerkin defect %.1e",
             spec.problem, problem.ndof, fine.ndof, disc, defect)
    return Reference(u_direct=u_h, fine=ref, discretization_error=disc, vectors=vectors,
                     info={"ndof": problem.ndof, "fine_ndof": fine.ndof, "galerkin_defect": defect,
                           "seconds": time.perf_counter() - t0})


def time_direct(problem: BenchProblem, options: RunOptions, repeats: int = 3) -> tuple[float, float]:
    """Best wall and best CPU time of ``repeats`` baseline solves of ``problem``.

    The baseline is the runner of ``problem.baseline``: the ``direct`` peer
    (factor and solve the reduced system), for contact the ``pdas`` peer.
    """
    runner = run_direct if problem.baseline == "direct" else get_method(problem.baseline, problem.kind).run
    wall = cpu = math.inf
    with threadpool_limits(limits=options.threads, user_api="blas"):
        for _ in range(max(int(repeats), 1)):
            t0, c0 = time.perf_counter(), time.process_time()
            runner(problem, None, options)
            wall, cpu = min(wall, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
    return wall, cpu


def warm_up(options: RunOptions) -> None:
    """Load the direct backend's library and pyamg once, so that no run pays for it."""
    import scipy.sparse as sp

    direct_solver(options.direct, sp.identity(2, format="csr"), threads=options.threads).solve(np.ones(2))
    try:
        import pyamg  # noqa: F401
    except ImportError:  # only the pyamg peer needs it
        pass


@dataclass
class CaseRecord:
    """Result of :func:`run_case` in the shape :func:`ddsolve.io.hdf5.write_result` stores.

    Attributes
    ----------
    values : dict
        Scalars (see :meth:`to_dict`).
    residuals : ndarray
        Empty (kept for the HDF5 layout).
    """

    values: dict[str, Any]
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def to_dict(self) -> dict[str, Any]:
        """problem, method, bodies, subdomains, elements, ndof, converged, iterations,
        wall_seconds, setup_seconds, direct_seconds, time_ratio, cpu_seconds, direct_cpu_seconds,
        cpu_ratio, algebraic_error, total_error,
        discretization_error, mem_mb, peak_rss_mb, direct_backend, threads, and method extras."""
        return dict(self.values)


def run_case(problem: BenchProblem, method: str, rtol: float | None, reference: Reference,
             options: RunOptions, *, repeats: int = 3) -> CaseRecord:
    """Run ``method`` once on ``problem`` and measure it.

    Parameters
    ----------
    problem : BenchProblem
    method : str
        A registered method (:data:`ddstudies.bench.methods.METHODS`) that solves ``problem.kind``.
    rtol : float or None
        Tolerance; ignored for non-iterative methods.
    reference : Reference
        From :func:`compute_reference` on the same problem.
    options : RunOptions
    repeats : int
        Runs of the method and of the direct baseline; times (and the
        method's ``setup_seconds``) are those of the fastest run, memory is
        measured on the first run, errors on the last.

    Returns
    -------
    CaseRecord
    """
    entry = get_method(method, problem.kind)
    rtol = rtol if entry.iterative else None
    if reference.u_direct.shape != (problem.ndof,):
        raise ValueError(f"reference has {reference.u_direct.size} dofs, the problem {problem.ndof}")
    warm_up(options)
    rss_start = current_rss_mb()
    wall, cpu, peak, extra = math.inf, math.inf, math.nan, {}
    with threadpool_limits(limits=options.threads, user_api="blas"):
        for k in range(max(int(repeats), 1)):
            t0, c0 = time.perf_counter(), time.process_time()
            run: MethodRun = entry.run(problem, rtol, options)
            seconds, cpu = time.perf_counter() - t0, min(cpu, time.process_time() - c0)
            if k == 0:
                peak = peak_rss_mb()
            if seconds < wall:
                wall, extra = seconds, run.extra
    direct_seconds, direct_cpu = time_direct(problem, options, repeats)
    spec: ProblemSpec = problem.spec
    values: dict[str, Any] = {
        "problem": problem.kind, "method": method, "bodies": spec.bodies, "subdomains": spec.subdomains,
        "elements": spec.elements, "ndof": problem.ndof, "converged": bool(run.converged),
        "iterations": int(run.iterations), "wall_seconds": wall,
        "setup_seconds": extra.get("setup_seconds"), "direct_seconds": direct_seconds,
        "time_ratio": wall / direct_seconds if direct_seconds > 0 else math.nan,
        "cpu_seconds": cpu, "direct_cpu_seconds": direct_cpu,
        "cpu_ratio": cpu / direct_cpu if direct_cpu > 0 else math.nan,
        "algebraic_error": energy_error(problem.A, run.u, reference.u_direct),
        "total_error": reference.fine.total_error(problem.A, run.u),
        "discretization_error": reference.discretization_error,
        "mem_mb": max(peak - rss_start, 0.0), "peak_rss_mb": peak,
        "direct_backend": options.direct, "threads": options.threads, "peer": entry.peer,
    }
    if problem.case_errors is not None:
        values.update(problem.case_errors(problem, run, reference))
    values.update({k: v for k, v in extra.items() if k not in values and np.isscalar(v)})
    log.info("%s %s rtol=%s: %.3f s (x%.2f direct), algebraic %.2e, total %.2e", problem.kind, method,
             rtol, wall, values["time_ratio"], values["algebraic_error"], values["total_error"])
    return CaseRecord(values)
