"""Entry points of a distributed solve: :func:`solve` (library) and :func:`main` (command line).

Under ``mpiexec`` the command line (:func:`ddsolve.cli.main`) validates the
input on every rank, agrees on the result over all ranks (:func:`agree_on_input`,
one allgather) and then calls :func:`main` here. Rank 0 alone prints the result and writes files. An
exception on any rank prints one line ``ddsolve: error: <rank r>: <message>``
on that rank and aborts the whole job (``MPI_Abort``): no rank hangs.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import sys
import time
from typing import Any, NoReturn

import numpy as np

from ..errors import InputError, OutputError
from ..result import SolveResult
from ..spec import ProblemSpec
from .comm import CountingComm

log = logging.getLogger(__name__)

__all__ = ["DISTRIBUTED", "METHODS", "MPI_ENV", "agree_on_input", "check_supported", "mpi_world_size", "solve",
           "main"]

#: Methods with a distributed implementation (problem poisson); ``mpiexec -n 1`` runs these distributed.
METHODS = ("fetidp", "bddc", "feti")
#: Distributed methods of every problem (``mpiexec -n P``, P >= 2; the others are refused).
DISTRIBUTED: dict[str, tuple[str, ...]] = {"poisson": METHODS, "multibody": ("feti-feti", "hybrid"),
                                           "contact": ("active-set",)}
#: Environment variables that mark a process started by mpiexec (MPICH/Hydra, Open MPI, PMIx).
MPI_ENV = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "PMIX_SIZE")
#: Set by srun in each task of a step (not in a batch script): srun -n P without a PMI plugin (MpiDefault=none,
#: no --mpi=pmi2) starts P processes that MPI sees as singletons, each solving the whole problem.
SLURM_STEP_ENV = "SLURM_STEP_NUM_TASKS"
#: Test hook: rank numbers (comma-separated); those ranks raise once their setup is done (tests of the
#: abort path only): a RuntimeError, or with ":interrupt" after the numbers a KeyboardInterrupt (Ctrl-C
#: seen by those ranks alone), with ":input" an InputError raised on those ranks only.
FAIL_ENV = "DDSOLVE_TEST_FAIL_RANK"
ABORT_GRACE_SECONDS = 1.0     # between the error line and MPI_Abort


def mpi_world_size(environ: dict | None = None) -> int | None:
    """The job size announced by the launcher's environment, or None outside mpiexec (no mpi4py import)."""
    env = os.environ if environ is None else environ
    for name in MPI_ENV:
        value = env.get(name)
        if value is not None:
            try:
                return int(value)
            except ValueError:
                return None
    tasks = env.get(SLURM_STEP_ENV, "")
    if tasks.isdigit() and int(tasks) > 1:      # srun's tasks without PMI: _world refuses them (MPI sees 1)
        return int(tasks)
    return None


def check_supported(spec: ProblemSpec, size: int, *, decomposition: bool = True) -> None:
    """Reject what the distributed solvers do not do, identically on every rank (before any MPI call).

    ``decomposition=False``: not the checks of the spec's decomposition (its subdomain count against the
    method and the ranks), for a caller that passes its own scene (whose parts decide; checked as the
    scene is cut).

    Raises
    ------
    InputError
        ``method`` outside :data:`METHODS` or a problem other than poisson; ``subdomains``
        (``parts``) when there are fewer subdomains than ranks.
    """
    if spec.method not in DISTRIBUTED.get(spec.problem, ()):
        listed = "; ".join(f"{p}: {', '.join(ms)}" for p, ms in DISTRIBUTED.items())   # the whole line fits
        raise InputError("method", f"{spec.problem}/{spec.method} is not distributed (mpiexec: {listed}); "
                                   f"run it without mpiexec")
    if spec.method == "hybrid" and spec.projection != "orthogonal":
        raise InputError("projection", f"{spec.projection!r} is not distributed for the hybrid method "
                                       f"(under mpiexec only 'orthogonal', the default)")
    if spec.primal != "vertices":
        raise InputError("primal", f"{spec.primal!r}: edge averages have no distributed (mpiexec) implementation "
                                   f"(run without mpiexec, or use 'vertices')")
    if not decomposition:
        return
    from ..prepared import check_decomposition
    check_decomposition(spec)
    bodies = {"multibody": spec.bodies ** 2, "contact": 2}.get(spec.problem, 1)      # as the scene builds them
    n_sub = bodies * (spec.parts if spec.mesh == "unstructured" else spec.subdomains ** 2)
    if spec.mesh_file and spec.mesh == "unstructured":
        return                          # the parts of a mesh file are counted once it is read (in solve)
    if n_sub < size:
        raise InputError("parts" if spec.mesh == "unstructured" else "subdomains",
                         f"{n_sub} subdomains for {size} ranks: need at least one subdomain per rank")


def _reduce(prob, comm: CountingComm, info: dict, setup_seconds: float, solve_seconds: float,
            n_factorizations: int) -> dict[str, Any]:
    """The per-rank figures of a solve reduced over ranks (collective: every rank calls it)."""
    from ..api import peak_rss_mb

    msgs, nbytes, _ = info["per_iteration"]
    return {"totals": comm.comm.allreduce(np.array([msgs, nbytes], dtype=float)),
            # the largest over the ranks: a rank whose coarse blocks are its own makes fewer (the coarse sums
            # run over the ranks that share a block); rank 0's own count under-reported (a review)
            "allreduces": comm.comm.allreduce(float(info["per_iteration"][2]), op=comm.MPI.MAX),
            "coarse": comm.comm.allreduce(info["coarse_seconds"], op=comm.MPI.MAX),
            "setup": comm.comm.allreduce(setup_seconds, op=comm.MPI.MAX),
            "solve": comm.comm.allreduce(solve_seconds, op=comm.MPI.MAX),
            "krylov": comm.comm.allreduce(info["krylov_seconds"], op=comm.MPI.MAX),
            "mpi_seconds": comm.comm.allgather(float(info.get("mpi_seconds", 0.0))),
            "n_fact": comm.comm.allreduce(int(n_factorizations)),
            "n_templates": comm.comm.allreduce(int(prob.sub.local.n_templates)),
            "timings": {k: comm.comm.allreduce(float(v), op=comm.MPI.MAX) for k, v in sorted(prob.timings.items())},
            "peak": comm.comm.allgather(peak_rss_mb())}


def _report(spec: ProblemSpec, prob, comm: CountingComm, red: dict[str, Any]) -> tuple[dict, dict]:
    """``extra`` entries of every distributed result (``n_ranks``, ``comm``, timings ...) and the sizes."""
    from ..api import _sizes

    t = red["timings"]
    extra: dict[str, Any] = {
        "n_ranks": comm.size,
        "comm": {"messages_per_iteration": float(red["totals"][0]), "bytes_per_iteration": float(red["totals"][1]),
                 "allreduces_per_iteration": red["allreduces"], "coarse_seconds": float(red["coarse"]),
                 "krylov_seconds": float(red["krylov"]),
                 # per rank: wall time inside MPI calls in the solve phase (transfers and waiting for the
                 # slowest rank; their spread measures the load imbalance)
                 "mpi_seconds": [round(s, 6) for s in red["mpi_seconds"]]},
        "n_templates": red["n_templates"],                          # summed over ranks (each factors its own)
        "timings": {"mesh": t.get("mesh", 0.0), "partition": t.get("partition", 0.0),
                    "assembly": t.get("assembly", 0.0),
                    "setup": max(red["setup"] - t.get("scene", 0.0) - t.get("assembly", 0.0), 0.0),
                    "solve": red["solve"]},
        "peak_rss_mb": max(red["peak"]),                            # the largest over ranks
        "peak_rss_mb_per_rank": [round(x, 1) for x in red["peak"]],
        "n_primal": int(prob.n_primal),                        # as the serial mesh report
        "mesh": spec.mesh,
        "parts": spec.parts if spec.mesh == "unstructured" else spec.subdomains ** 2}
    return extra, _sizes(spec)                                      # as the serial result


def _result(spec: ProblemSpec, prob, out, info: dict, setup_seconds: float, solve_seconds: float,
            comm: CountingComm) -> SolveResult | None:
    """The :class:`SolveResult` on rank 0 (None elsewhere), with ``n_ranks`` and ``comm`` in ``extra``."""
    from ..api import _scalar_extras
    from ..krylov import attained

    red = _reduce(prob, comm, info, setup_seconds, solve_seconds, out.n_factorizations)
    if comm.rank != 0:
        return None
    kr = out.krylov
    from ..dd.check import judged
    converged, reason = judged(*attained(kr, spec.rtol), out.extra, spec.rtol, spec.method)   # as serial
    extra: dict[str, Any] = _scalar_extras(out.extra)
    extra["restarts"] = int(getattr(kr, "restarts", 0))
    extra["preset"] = spec.preset
    common, sizes = _report(spec, prob, comm, red)
    fields: dict[str, Any] = dict(u=out.u, nlambda=out.nlambda, n_factorizations=red["n_fact"],
                                  setup_seconds=red["setup"], solve_seconds=red["solve"],
                                  converged=converged, reason=reason, iterations=kr.iterations,
                                  residuals=np.asarray(kr.residuals, dtype=float), true_residual=kr.true_residual)
    if spec.cond and kr.cond is not None:
        fields.update(cond=kr.cond, lambda_min=kr.lambda_min, lambda_max=kr.lambda_max)
    if fields["converged"] and out.u is not None and not np.all(np.isfinite(out.u)):
        fields.update(converged=False, reason=f"non-finite solution after {reason}")
    if spec.check and out.u is not None:       # the direct reference, on rank 0 only (serial assembly)
        from ..api import checked_error
        from ..prepared import prepare
        ref_sub = prepare(spec, prob.scene).sub
        if spec.problem == "multibody":
            from ..multibody import GlobalInterface
            from ..multibody.direct import solve_constrained_direct
            gi = GlobalInterface(ref_sub)
            reference = solve_constrained_direct(ref_sub, gi, gi.contact_mask(spec.contact))
        else:
            from ..dd import solve_direct
            reference = solve_direct(ref_sub)
        error, why = checked_error(ref_sub.global_matrix(), out.u, reference)
        fields["error_vs_direct"] = error
        if why:
            extra["check_reason"] = why
    extra.update(common)
    bodies = prob.pieces.get("n_bodies_result", spec.bodies)
    return SolveResult(problem=spec.problem, method=spec.method, bodies=bodies, **sizes,
                       ndof=prob.ndof, **fields, extra=extra)


def _solve_contact(spec: ProblemSpec, prob, comm: CountingComm, prep_seconds: float,
                   options: dict, gather: bool = True) -> SolveResult | None:
    """The active set method over ranks; the KKT residuals and energy distributed (``--check``: rank 0 assembles)."""
    from .active_set import DistributedActiveSetHybrid

    start = comm.counters.snapshot()
    t0 = time.perf_counter()
    solver = DistributedActiveSetHybrid(prob, gather=gather or spec.check)
    setup = time.perf_counter() - t0
    mpi0 = comm.counters.seconds
    sol = solver.solve(rtol=spec.rtol, pcg_rtol=spec.rtol, maxiter=spec.maxiter, **options)
    total = time.perf_counter() - t0
    end = comm.counters.snapshot()
    its = max(int(sol.total_iterations), 1)
    faces = solver.hybrid.face_solves
    info = {"per_iteration": tuple((b - a) / its for a, b in zip(start, end)),
            "coarse_seconds": (solver.dh.body_solver.coarse_seconds + solver.dh.local_solver.coarse_seconds),
            "krylov_seconds": float(sum(f["krylov_seconds"] for f in faces)),
            "mpi_seconds": comm.counters.seconds - mpi0}
    red = _reduce(prob, comm, info, prep_seconds + setup, total - setup, solver.dh.n_factorizations)
    # the KKT residuals (5.5) and the energy from every rank's own subdomains (no assembled K, f, B)
    measures = solver.measures(sol)
    if comm.rank != 0:
        return None
    from ..contact.run import contact_fields
    fields = contact_fields(spec, sol, measures)
    if spec.check:                 # the direct reference, on rank 0 only (serial assembly, as for poisson)
        from ..contact.run import check_fields
        from ..prepared import prepare
        check_fields(spec, prepare(spec, prob.scene).contact, sol, fields)
    fields["setup_seconds"], fields["solve_seconds"] = red["setup"], red["solve"]
    fields["n_factorizations"] = red["n_fact"]
    common, sizes = _report(spec, prob, comm, red)
    fields["extra"].update(common)
    bodies = prob.pieces.get("n_bodies_result", spec.bodies)
    result = SolveResult(problem=spec.problem, method=spec.method, bodies=bodies, **sizes,
                         ndof=prob.ndof, **fields)
    if spec.output:                # rank 0 alone writes; the gap of the file needs the serial B (as --check)
        from ..api import _write_output
        from ..prepared import prepare
        _write_output(spec, prepare(spec, prob.scene), result.u, sol.lam, result)
    return result


def _prepare_agreed(spec: ProblemSpec, comm: CountingComm, scene):
    """:func:`prepare_rank`, with its input errors agreed on by every rank.

    The rank setup communicates nothing, so every rank reaches the one allgather here: an
    :class:`InputError` of any rank (a mesh file that is not a netgen mesh, fewer METIS parts of a
    mesh file than ranks, a file that one rank cannot read) is raised on every rank, the lowest
    failing rank's, marked ``every_rank`` (the command line then prints it and exits 2 on every
    rank, with no ``MPI_Abort``). Any other exception propagates (and aborts the job).
    """
    from .setup import prepare_rank

    prob, error = None, None
    try:
        prob = prepare_rank(spec, comm, scene)
    except InputError as exc:
        error = (exc.field, exc.message)
    errors = [e for e in comm.comm.allgather(error) if e is not None]
    if errors:
        exc = InputError(*errors[0])
        exc.every_rank = True
        raise exc
    return prob


def solve(spec: ProblemSpec | dict, scene=None, comm: Any = None, *, gather: bool = True) -> SolveResult | None:
    """Distributed solve of ``spec`` (a method of :data:`DISTRIBUTED`) over the ranks of ``comm``.

    Parameters
    ----------
    spec : ProblemSpec or dict
    scene : Scene, optional
        Instead of the spec's structured scene (e.g. :func:`ddsolve.scene.unstructured_scene`),
        read on rank 0: the other ranks may pass None (rank 0 sends them their part) or the same
        scene (each cuts its own part; needed for a callable load ``scene.f``).
    comm : mpi4py communicator or CountingComm, optional
        ``MPI.COMM_WORLD`` by default.
    gather : bool
        Assemble the global solution ``u`` on rank 0.

    Returns
    -------
    SolveResult on rank 0 (``extra`` holds ``n_ranks`` and ``comm``), None on the other ranks.

    Raises
    ------
    InputError
        On every rank, before any communication: what :func:`check_supported` refuses (a method that
        is not distributed, ``primal="vertices+edges"``, a projection other than the orthogonal one
        for the hybrid method, fewer subdomains than ranks).
    """
    from threadpoolctl import threadpool_limits

    from .bddc import solve_bddc_mpi
    from .feti import solve_feti_mpi
    from .fetidp import solve_fetidp_mpi
    from .fetifeti import solve_fetifeti_mpi
    from .hybrid import solve_hybrid_mpi

    if not isinstance(spec, ProblemSpec):
        spec = ProblemSpec.from_mapping(spec)
    if comm is None:
        from mpi4py import MPI
        comm = MPI.COMM_WORLD
    if not isinstance(comm, CountingComm):
        comm = CountingComm(comm)
    # the command line's checks, the same on every rank (no collective): a method that is not distributed
    # made rank 0 raise while the others waited in a broadcast forever (a review)
    check_supported(spec, comm.size, decomposition=scene is None)    # a given scene's parts decide (a review)
    with threadpool_limits(limits=1, user_api="blas"):
        t0 = time.perf_counter()
        prob = _prepare_agreed(spec, comm, scene)
        if spec.mesh_file:    # the JSON's bodies: the mesh file's (each rank holds the bodies of its subdomains)
            owned = prob.sub.scene.subdomain_body
            prob.pieces["n_bodies_result"] = max(comm.comm.allgather(int(owned.max()) + 1 if owned.size else 0))
        prep_seconds = time.perf_counter() - t0
        fail_ranks, _, fail_kind = os.environ.get(FAIL_ENV, "").partition(":")
        if str(comm.rank) in fail_ranks.split(","):
            if fail_kind == "interrupt":
                raise KeyboardInterrupt
            if fail_kind == "input":
                raise InputError("test", f"injected input error ({FAIL_ENV})")
            raise RuntimeError(f"injected failure ({FAIL_ENV}={fail_ranks})")
        method = {"fetidp": solve_fetidp_mpi, "bddc": solve_bddc_mpi, "feti": solve_feti_mpi,
                  "feti-feti": solve_fetifeti_mpi, "hybrid": solve_hybrid_mpi, "active-set": None}[spec.method]
        t1 = time.perf_counter()
        from ..presets import solver_options
        options = solver_options(spec.preset, spec.problem, spec.method)
        gather = gather or bool(spec.output)
        if spec.problem == "contact":
            return _solve_contact(spec, prob, comm, prep_seconds, options, gather)
        if spec.method == "hybrid":
            options.update(norm=spec.norm, projection=spec.projection)
        mpi0 = comm.counters.seconds
        out, info = method(prob, rtol=spec.rtol, maxiter=spec.maxiter, cond=spec.cond,
                           gather=gather or spec.check, **options)
        total = time.perf_counter() - t1
        # time inside MPI calls in the solve phase (after the method's own setup: its first coarse solve waits
        # there for the slowest rank's setup), so that the spread over ranks is the imbalance of the solve
        info = {**info, "mpi_seconds": comm.counters.seconds - info.pop("mpi_at_setup", mpi0)}
        result = _result(spec, prob, out, info, prep_seconds + out.setup_seconds, total - out.setup_seconds, comm)
        if result is not None and spec.output:        # rank 0 alone writes, after the timed solve (as serial)
            from types import SimpleNamespace

            from ..api import _write_output
            _write_output(spec, SimpleNamespace(scene=prob.scene, sub=prob.topo, contact=None), result.u,
                          result=result)
        return result


def _world():
    """(MPI.COMM_WORLD, None), or (None, the error line) without a working mpi4py or with one whose MPI is not
    the launcher's (each process would be a job of its own, solving the whole problem)."""
    size = mpi_world_size()
    try:
        from mpi4py import MPI
    except Exception as exc:     # noqa: BLE001 - not installed, or broken (its MPI library fails to load)
        return None, f"mpi: running under mpiexec with {size} ranks needs mpi4py ({exc})"
    comm = MPI.COMM_WORLD
    if size is not None and comm.Get_size() != size:
        if not any(name in os.environ for name in MPI_ENV):      # srun started them, with no PMI for MPI
            return None, (f"mpi: srun started {size} tasks but MPI sees {comm.Get_size()}: no PMI (SLURM's "
                          f"MpiDefault=none?); use srun --mpi=pmi2 (see srun --mpi=list), or mpiexec")
        return None, (f"mpi: the launcher started {size} processes but MPI sees {comm.Get_size()}: mpiexec is "
                      f"not the one of mpi4py's MPI ({MPI.Get_library_version().splitlines()[0].strip()}); use "
                      f"its mpiexec (the mpich package's)")
    return comm, None


def _compared(spec: ProblemSpec) -> dict[str, Any]:
    """The fields of ``spec`` that every rank must agree on: all of them, the files of rank 0 alone (the mesh
    file it reads, the output it writes) only as given or not (their paths may differ on node-local disks;
    whether an output is written decides whether the solution is gathered, which is collective)."""
    from ..scene_file import PATH_FIELDS

    fields = spec.to_dict()
    for name in PATH_FIELDS:
        fields[name] = "<given>" if fields.get(name) else None
    return fields


def agree_on_input(error: InputError | None, spec: ProblemSpec | None = None) -> tuple[InputError | None, int | None]:
    """Agree on the command line's input checks over all ranks (P > 1), before any other MPI call.

    Every rank checked the input on its own; one allgather gives every rank the lowest failing
    rank's :class:`InputError` (or None), so that all ranks exit 2 together or go on together.
    The same allgather compares the ranks' specs (``spec``, parsed by each rank from its own
    arguments and scene file): ranks given different input (an MPMD launch, or a scene file of one
    name with other contents on node-local disks) ran different algorithms and waited for each
    other forever (a review). They now exit 2 together, naming the first field that differs.

    Returns
    -------
    (error, status)
        The agreed error and None; or (None, 2) after printing one line when there is no
        working mpi4py or its MPI does not match the launcher (then nothing can be agreed on).
    """
    comm, problem = _world()
    if problem is not None:
        sys.stderr.write(f"ddsolve: error: {problem}\n")
        return None, 2
    mine = None if error is None else (error.field, error.message)
    gathered = comm.allgather((mine, None if spec is None else _compared(spec)))
    errors = [e for e, _ in gathered if e is not None]
    if errors:
        return InputError(*errors[0]), None
    first = gathered[0][1]
    for rank, (_, other) in enumerate(gathered):
        differ = sorted(k for k in first.keys() | other.keys() if repr(first.get(k)) != repr(other.get(k)))
        if differ:
            k = differ[0]
            return InputError("input", f"rank {rank} was given other input than rank 0 ({k}: {other.get(k)!r}, "
                                       f"rank 0: {first.get(k)!r}); every rank needs the same arguments and scene "
                                       "file"), None
    return None, None


def main(spec: ProblemSpec, as_json: bool, human) -> int | None:
    """Command-line solve under mpiexec; the input is already validated. Returns 0 or 2 (or aborts the job);
    None on one rank without a working mpi4py (the caller then runs the serial solver: the same answer)."""
    comm, problem = _world()
    if problem is not None:
        if mpi_world_size() in (None, 1):      # one process: MPI cannot mismatch, so mpi4py is what is missing
            log.info("mpiexec -n 1 without a working mpi4py: the serial solver runs (%s)", problem)
            return None
        sys.stderr.write(f"ddsolve: error: {problem}\n")
        return 2
    if comm.Get_rank() != 0:        # the ranks run the same algorithm: rank 0 alone logs its warnings (and -v)
        root = logging.getLogger()
        root.setLevel(max(root.getEffectiveLevel(), logging.ERROR))
    try:
        result = solve(spec, comm=comm, gather=spec.check)
        if comm.Get_rank() != 0:
            # done: rank 0 alone goes on (--check, --output). A Ctrl-C now is rank 0's to report (130);
            # one that killed this rank while it exited made the job's status that of the signal, 2, the
            # status of an input error; a SIGTERM that ended this rank at once made the launcher kill
            # rank 0 inside its --output write, before its handler removed the temporary file (a review)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if comm.Get_rank() == 0:
            summary = result.to_dict()
            print(json.dumps(summary) if as_json else human(summary), flush=True)
    except OutputError as exc:     # rank 0 alone writes, after the last collective: print what was computed
        if exc.result is not None:
            print(json.dumps(exc.result.to_dict()) if as_json else human(exc.result.to_dict()), flush=True)
        os.write(2, f"ddsolve: error: {exc}\n".encode(errors="replace"))
        return 2
    except InputError as exc:
        if not getattr(exc, "every_rank", False):
            _abort(comm, exc)
        sys.stderr.flush()                                   # raised on every rank alike: no abort needed
        os.write(2, f"ddsolve: error: {exc}\n".encode(errors="replace"))     # one write: lines never interleave
        return 2
    except KeyboardInterrupt:
        # Ctrl-C: a rank waiting inside an MPI call never sees its own SIGINT, so returning 130 here
        # left the job hanging (a review); the whole job ends, with the status of an interrupt
        _abort(comm, line=f"ddsolve: interrupted (rank {comm.Get_rank()})\n", code=130)
    except Exception as exc:     # noqa: BLE001 - any failure on any rank ends the whole job
        _abort(comm, exc)
    return 0


def _abort(comm, exc: BaseException | None = None, *, line: str | None = None, code: int = 1) -> NoReturn:
    """One line (default ``ddsolve: error: rank <r>: <type>: <message>``), then ``MPI_Abort`` of the whole job.

    The process never returns: MPICH lets ``MPI_Abort`` return on some ranks when several call it at
    once (a review: the line was then printed twice, and the rank went on), so it exits after it.
    """
    if line is None:
        line = f"ddsolve: error: rank {comm.Get_rank()}: {type(exc).__name__}: {exc}\n"
    sys.stderr.flush()
    os.write(2, line.encode(errors="replace"))                    # one unbuffered write
    # MPI_Abort makes the launcher kill every process at once; give it time to forward the line
    # first (without the pause a loaded machine lost it now and then).
    try:
        time.sleep(ABORT_GRACE_SECONDS)
    except KeyboardInterrupt:              # a second Ctrl-C must not skip the abort (the other ranks would hang)
        pass
    try:
        comm.Abort(code)
    finally:
        os._exit(code)
