"""Distributed BDDC (Section 2.7): interface dofs shared between the ranks that touch them.

A rank holds the global interface dofs of its subdomains (sorted by global
dof); a dof on subdomains of several ranks is held by each of them (the
lowest owns it for inner products). S^_Gamma and the preconditioner
R_D^T S~^{-1} R_D are the serial local operators followed by one
:class:`~ddsolve.parallel.comm.NeighbourSum`; S~^{-1} needs one Allreduce of
the primal right-hand side. Per iteration: 2 neighbour exchanges, 4
Allreduces (3 of PCG, 1 coarse).
"""
from __future__ import annotations

import time

import numpy as np

from ..dd.bddc import InterfaceMap
from ..dd.common import MethodOutput
from ..dd.operators import DirichletSchur, linear_operator
from ..krylov.result import KrylovResult
from .coarse import DistributedPrimalSolver
from .comm import NeighbourSum, shared_indices
from .krylov import distributed_pcg
from .setup import RankProblem, gather_solution

__all__ = ["solve_bddc_mpi", "distribute_bddc"]


def distribute_bddc(topo, rank_of_sub: np.ndarray, size: int, spec=None) -> list[dict]:
    """What each rank's BDDC needs from the global topology (computed on rank 0 and sent).

    Returns, per rank, ``{"interface": SharedIndex, "interface_dofs": ndarray, "n_interface": int}``:
    the sharing of its interface dofs, those dofs (sorted global numbers, as
    :class:`~ddsolve.dd.bddc.InterfaceMap` lists them; the rank checks them) and the global number
    of interface dofs.
    """
    all_gamma = np.flatnonzero(topo.interface)
    gid = topo.l2g[all_gamma]
    n_interface = int(np.unique(gid).size)
    return [{"interface": shared, "interface_dofs": dofs, "n_interface": n_interface}
            for dofs, shared in shared_indices(gid, rank_of_sub[topo.sub_of_W[all_gamma]], size, topo.ndof)]


def solve_bddc_mpi(prob: RankProblem, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
                   gather: bool = True) -> tuple[MethodOutput, dict]:
    """BDDC on the ranks of ``prob.comm``; the serial :func:`ddsolve.dd.solve_bddc`, distributed.

    Returns ``(output, info)`` as :func:`ddsolve.parallel.fetidp.solve_fetidp_mpi`.
    """
    comm, sub = prob.comm, prob.sub
    t0 = time.perf_counter()
    cache: dict = {}
    schur = DirichletSchur(sub, sub.interface, cache)
    schur.explicit                                      # decided (dense blocks formed) in the setup
    primal_solver = DistributedPrimalSolver(sub, sub.vertex, cache, comm, prob.primal_dofs)
    primal_solver.assemble_basis()                      # in the setup, not in the first solve
    iface = InterfaceMap(sub, sub.interface)                       # this rank's interface dofs (global ids)
    scatter, gather, delta_g = iface.scatter, iface.gather, iface.delta
    shared, n_interface = prob.pieces["interface"], prob.pieces["n_interface"]    # from rank 0 (distribute_bddc)
    if not np.array_equal(prob.pieces["interface_dofs"], iface.dofs):
        raise RuntimeError("the interface dofs sent by rank 0 are not this rank's")
    exchange = NeighbourSum(comm, shared)
    n_g = iface.n

    def S_hat(u_g: np.ndarray) -> np.ndarray:
        return exchange.sum(gather(schur.matvec(scatter(u_g))))

    def M(r_g: np.ndarray) -> np.ndarray:
        return exchange.sum(gather(primal_solver.solve(scatter(r_g, delta_g)), delta_g))

    g = exchange.sum(gather(schur.harmonic_extension_rhs(sub.f_W)))
    setup = time.perf_counter() - t0
    mpi_at_setup = comm.counters.seconds          # the solve's MPI time starts here
    t1 = time.perf_counter()
    if n_interface == 0:    # every interface node primal, or no interface (a tiny mesh): as serial
        kr = KrylovResult.solved_directly(n_g, "interface unknowns")
        per_iteration = (0.0, 0.0, 0.0)
    else:
        kr, per_iteration = distributed_pcg(linear_operator(n_g, S_hat), g, comm=comm, owned=shared.owned,
                                            rtol=rtol, maxiter=maxiter, M=linear_operator(n_g, M), cond=cond)
    krylov_seconds = time.perf_counter() - t1
    u_W = schur.interior_solution(sub.f_W, scatter(kr.x))
    u = gather_solution(prob, u_W) if gather else None
    out = MethodOutput(u=u, krylov=kr, nlambda=0,
                       n_factorizations=primal_solver.n_factorizations + schur.II.n_new_factorizations,
                       setup_seconds=setup, extra={"n_primal": primal_solver.n_primal, "n_interface": n_interface})
    info = {"mpi_at_setup": mpi_at_setup,
            "coarse_seconds": primal_solver.coarse_seconds, "krylov_seconds": krylov_seconds,
            "per_iteration": per_iteration}
    return out, info
