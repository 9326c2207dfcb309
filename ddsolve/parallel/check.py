"""The final error check of FETI and FETI-DP (:mod:`ddsolve.dd.check`), distributed.

The serial estimate sqrt(r^T M^{-1} r / f^T u), with M^{-1} a BDDC preconditioner of the same
subdomains and rho-scaling weights, computed from each rank's subdomains: the interface values
(the averaged u, the assembled residual and load, the weights) are completed by neighbour sums
over the interface dofs, and the inner products and norms by scalar Allreduces (five), over the interior
entries and the owned interface dofs. It equals the serial estimate up to the summation order.
"""
from __future__ import annotations

import math

import numpy as np

from ..dd.bddc import InterfaceMap
from ..dd.operators import DirichletSchur
from .coarse import DistributedPrimalSolver
from .comm import CountingComm, NeighbourSum, SharedIndex

__all__ = ["distributed_error_estimate", "distributed_needs_check", "interface_pieces"]


def distributed_needs_check(sub, comm: CountingComm) -> bool:
    """:func:`ddsolve.dd.check.needs_check` over the subdomains of all ranks (two Allreduces)."""
    rho = np.asarray(sub.rho, dtype=float)
    high = comm.allreduce_scalar(float(rho.max()) if rho.size else -math.inf, op="max")
    low = -comm.allreduce_scalar(-float(rho.min()) if rho.size else -math.inf, op="max")
    return high > low


def interface_pieces(topo, rank_of_sub: np.ndarray, size: int) -> list[dict]:
    """Per rank, the sharing of its interface dofs (``"interface"``) and those dofs (``"interface_dofs"``),
    as :func:`ddsolve.parallel.bddc.distribute_bddc` sends them (computed on rank 0)."""
    from .bddc import distribute_bddc

    return distribute_bddc(topo, rank_of_sub, size)


def distributed_error_estimate(sub, u_W: np.ndarray, primal_solver: DistributedPrimalSolver,
                               schur: DirichletSchur, comm: CountingComm, pieces: dict) -> float:
    """The rank's share of :func:`ddsolve.dd.check.energy_error_estimate`, the same value on every rank.

    Parameters
    ----------
    sub : RankSubstructures
    u_W : ndarray, shape (n_W,)
        The solve's W values on this rank's subdomains (copies not yet averaged).
    primal_solver, schur : DistributedPrimalSolver, DirichletSchur
        A~^{-1} (with its coarse Allreduce) and the local Dirichlet problems.
    comm : CountingComm
    pieces : dict
        ``"interface"`` (SharedIndex) and ``"interface_dofs"`` (:func:`interface_pieces`).
    """
    iface = InterfaceMap(sub, sub.interface)
    shared: SharedIndex = pieces["interface"]
    if not np.array_equal(pieces["interface_dofs"], iface.dofs):
        raise RuntimeError("the interface dofs sent by rank 0 are not this rank's")
    exchange = NeighbourSum(comm, shared)
    owned = shared.owned
    interior = np.ones(sub.n_W, dtype=bool)
    interior[iface.entries] = False

    def assembled(w: np.ndarray) -> np.ndarray:           # interface values of R^T w
        return exchange.sum(iface.gather(w))

    def total(local: float) -> float:
        return comm.allreduce_scalar(float(local))

    local_bad = 0.0 if np.all(np.isfinite(u_W)) else 1.0
    if total(local_bad) > 0:
        return math.inf
    u_g = exchange.sum(iface.gather(u_W, iface.delta))     # R_D^T u_W on the interface (the averaged u)
    u_c = u_W.copy()
    u_c[iface.entries] = u_g[iface.position]
    f_g = assembled(sub.f_W)
    local_max = max(float(np.max(np.abs(sub.f_W[interior]), initial=0.0)),
                    float(np.max(np.abs(f_g), initial=0.0)))
    exponent = int(np.frexp(comm.allreduce_scalar(local_max, op="max"))[1])    # scale-free, as serial
    f_W, u_c, u_g, f_g = (np.ldexp(v, -exponent) for v in (sub.f_W, u_c, u_g, f_g))
    Ku = sub.K_W @ u_c
    rK = Ku - f_W
    r_g = assembled(Ku) - f_g
    r_norm = total(np.sum(np.abs(rK[interior])) + np.sum(np.abs(r_g[owned])))
    if r_norm == 0:
        return 0.0
    energy = total(f_W[interior] @ u_c[interior] + f_g[owned] @ u_g[owned])
    if not energy > 0:
        return math.inf
    rho_W = sub.rho[sub.sub_of_W]
    weights = np.ones(sub.n_W)
    weights[iface.entries] = rho_W[iface.entries] / assembled(rho_W)[iface.position]
    w_g = weights[iface.entries]
    r_W = rK.copy()
    r_W[iface.entries] = r_g[iface.position]
    r_W *= weights
    g = assembled(schur.harmonic_extension_rhs(r_W))
    z_g = exchange.sum(iface.gather(primal_solver.solve(iface.scatter(g, w_g)), w_g))
    z_W = schur.interior_solution(r_W, iface.scatter(z_g))
    rz = total(rK[interior] @ z_W[interior] + r_g[owned] @ z_g[owned])
    return math.sqrt(abs(rz) / energy)
