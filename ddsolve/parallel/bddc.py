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
from .coarse import DistributedPrimalSolver
from .comm import NeighbourSum, SharedIndex
from .krylov import distributed_pcg
from .setup import RankProblem, gather_solution

__all__ = ["solve_bddc_mpi"]


def solve_bddc_mpi(prob: RankProblem, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
                   gather: bool = True) -> tuple[MethodOutput, dict]:
    """BDDC on the ranks of ``prob.comm``; the serial :func:`ddsolve.dd.solve_bddc`, distributed.

    Returns ``(output, info)`` as :func:`ddsolve.parallel.fetidp.solve_fetidp_mpi`.
    """
    comm, sub, topo = prob.comm, prob.sub, prob.topo
    t0 = time.perf_counter()
    cache: dict = {}
    schur = DirichletSchur(sub, sub.interface, cache)
    primal_solver = DistributedPrimalSolver(sub, sub.vertex, cache, comm, np.unique(topo.l2g[topo.vertex]))
    iface = InterfaceMap(sub, sub.interface)                       # this rank's interface dofs (global ids)
    dofs, scatter, gather, delta_g = iface.dofs, iface.scatter, iface.gather, iface.delta
    all_gamma = np.flatnonzero(topo.interface)
    n_interface = int(np.unique(topo.l2g[all_gamma]).size)
    shared = SharedIndex.build(comm.rank, dofs, topo.l2g[all_gamma],
                               prob.rank_of_sub[topo.sub_of_W[all_gamma]], topo.ndof)
    exchange = NeighbourSum(comm, shared)
    n_g = iface.n

    def S_hat(u_g: np.ndarray) -> np.ndarray:
        return exchange.sum(gather(schur.matvec(scatter(u_g))))

    def M(r_g: np.ndarray) -> np.ndarray:
        return exchange.sum(gather(primal_solver.solve(scatter(r_g, delta_g)), delta_g))

    g = exchange.sum(gather(schur.harmonic_extension_rhs(sub.f_W)))
    setup = time.perf_counter() - t0
    t1 = time.perf_counter()
    kr, per_iteration = distributed_pcg(linear_operator(n_g, S_hat), g, comm=comm, owned=shared.owned, rtol=rtol,
                         maxiter=maxiter, M=linear_operator(n_g, M), cond=cond)
    krylov_seconds = time.perf_counter() - t1
    u_W = schur.interior_solution(sub.f_W, scatter(kr.x))
    u = gather_solution(prob, u_W) if gather else None
    out = MethodOutput(u=u, krylov=kr, nlambda=0,
                       n_factorizations=primal_solver.n_factorizations + schur.II.n_new_factorizations,
                       setup_seconds=setup, extra={"n_primal": primal_solver.n_primal, "n_interface": n_interface})
    info = {"coarse_seconds": primal_solver.coarse_seconds, "krylov_seconds": krylov_seconds,
            "per_iteration": per_iteration}
    return out, info
