"""Run under mpiexec by test_kkt_mpi.py: the KKT residuals (5.5) of a distributed contact solve.

Usage: kkt_case.py {structured,unstructured} {0,1 (check)} OUT.npz

1. The distributed active set solve, then :meth:`DistributedActiveSetHybrid.measures` (collective), and on
   rank 0 the serial :meth:`ContactProblem.kkt` / ``energy`` of the same gathered u and lambda.
2. :func:`ddsolve.parallel.solve` with ``ddsolve.prepared.prepare`` counting its calls on every rank.
3. :func:`ddsolve.parallel.solve` with ``gather=check``, as the command line calls it.
Rank 0 writes both into OUT.npz.
"""
import sys

import numpy as np
from mpi_case import case

import ddsolve.prepared as prepared
from ddsolve.contact.run import ContactMeasures
from ddsolve.parallel import solve
from ddsolve.parallel.active_set import DistributedActiveSetHybrid
from ddsolve.parallel.comm import CountingComm
from ddsolve.parallel.setup import prepare_rank
from ddsolve.presets import solver_options
from ddsolve.spec import ProblemSpec

KEYS = ("kkt_feasibility", "kkt_dual_feasibility", "kkt_complementarity", "kkt_stationarity", "kkt_residual")


def main(kind: str, check: bool, out: str) -> None:
    from mpi4py import MPI
    comm = CountingComm(MPI.COMM_WORLD)
    spec_map, scene = case("active-set", kind)
    spec = ProblemSpec.from_mapping({**spec_map, "check": check})
    # 1. the same (u, lambda) evaluated distributed and serially
    prob = prepare_rank(spec, comm, scene)
    solver = DistributedActiveSetHybrid(prob)
    sol = solver.solve(rtol=spec.rtol, pcg_rtol=spec.rtol, maxiter=spec.maxiter,
                       **solver_options(spec.preset, spec.problem, spec.method))
    dist = solver.measures(sol)
    # 2. the solve of the command line, prepare() counted
    calls = []
    original = prepared.prepare

    def counting(*args, **kwargs):
        calls.append(args[0].problem)
        return original(*args, **kwargs)

    prepared.prepare = counting
    result = solve(spec, scene=scene, comm=comm)
    prepared.prepare = original
    # 3. as the command line runs it without --check: no global u anywhere (gather=False)
    bare = solve(spec, scene=scene, comm=comm, gather=spec.check)
    n_calls = comm.comm.gather(len(calls), root=0)
    if comm.rank != 0:
        return
    ser = ContactMeasures.of(prepared.prepare(spec, scene).contact, sol.u, sol.lam)   # test only, after the solve
    e = result.extra
    np.savez(out, n_ranks=comm.size, converged=bool(sol.converged), dist=_row(dist), serial=_row(ser),
             result=np.array([e[k] for k in KEYS] + [e["energy"]]), n_contact=[dist.n_contact, ser.n_contact],
             prepare_calls=np.array(n_calls), result_converged=result.converged, u=sol.u, lam=sol.lam,
             bare_u_is_none=bare.u is None, bare_result=np.array([bare.extra[k] for k in KEYS] + [bare.extra["energy"]]),
             bare_iterations=[bare.iterations, result.iterations],
             weighted=[dist.weighted_feasibility, ser.weighted_feasibility, e["kkt_weighted_feasibility"]])


def _row(m: ContactMeasures) -> np.ndarray:
    d = m.kkt.as_dict()
    return np.array([d[k] for k in KEYS] + [m.energy])


if __name__ == "__main__":
    try:
        main(sys.argv[1], sys.argv[2] == "1", sys.argv[3])
    except Exception:                   # noqa: BLE001 - one failing rank ends the job (no hang until the timeout)
        import traceback

        from mpi4py import MPI
        traceback.print_exc()
        MPI.COMM_WORLD.Abort(1)
