"""The final error checks of FETI and FETI-DP (:mod:`ddsolve.dd.check`) and of FETI-FETI and the hybrid
method (:mod:`ddsolve.multibody.check`), distributed.

The serial estimate sqrt(r^T M^{-1} r / f^T u) plus its rounding floor, with M^{-1} a BDDC
preconditioner of the same subdomains and rho-scaling weights, computed from each rank's subdomains:
the interface values (the averaged u, the assembled residual and load, the weights) are completed by
neighbour sums over the interface dofs, and the inner products and norms by scalar Allreduces (seven),
over the interior entries and the owned interface dofs. It equals the serial estimate up to the
summation order.
"""
from __future__ import annotations

import copy
import math

import numpy as np

from ..dd.bddc import InterfaceMap
from ..dd.check import EPS, absolute_product, loose_tolerance, rounding_signs
from ..dd.operators import DirichletSchur
from ..multibody.check import floating_shifts, tied_nodes, tied_scene
from .coarse import DistributedPrimalSolver
from .comm import CountingComm, NeighbourSum, SharedIndex

__all__ = ["distributed_error_estimate", "distributed_needs_check", "interface_pieces", "tied_pieces",
           "distributed_multibody_estimate"]


def distributed_needs_check(sub, comm: CountingComm, rtol: float | None = None) -> bool:
    """:func:`ddsolve.dd.check.needs_check` over the subdomains of all ranks (two Allreduces; none for a
    general mesh, ``sub.templates`` False on every rank alike, or a loose ``rtol``, the same on every rank)."""
    if not sub.templates or loose_tolerance(rtol):
        return True
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
    u_norm = total(np.sum(np.abs(u_c[interior])) + np.sum(np.abs(u_g[owned])))
    r_norm = total(np.sum(np.abs(rK[interior])) + np.sum(np.abs(r_g[owned])))
    if r_norm == 0 and u_norm == 0:
        return 0.0
    energy = total(f_W[interior] @ u_c[interior] + f_g[owned] @ u_g[owned])
    if not energy > 0:
        return math.inf
    rho_W = sub.rho[sub.sub_of_W]
    weights = np.ones(sub.n_W)
    weights[iface.entries] = rho_W[iface.entries] / assembled(rho_W)[iface.position]
    w_g = weights[iface.entries]

    def eta(res_W: np.ndarray, res_g: np.ndarray) -> float:     # res: interior entries and interface dofs
        r_W = res_W.copy()
        r_W[iface.entries] = res_g[iface.position]
        r_W *= weights
        g = assembled(schur.harmonic_extension_rhs(r_W))
        z_g = exchange.sum(iface.gather(primal_solver.solve(iface.scatter(g, w_g)), w_g))
        z_W = schur.interior_solution(r_W, iface.scatter(z_g))
        rz = total(res_W[interior] @ z_W[interior] + res_g[owned] @ z_g[owned])
        return math.sqrt(abs(rz) / energy)

    # the model of the computed residual's rounding, eps (|A| |u| + |f|) with signs by global dof, as serial
    Ku_abs = absolute_product(sub.K_W, u_c)
    noise_W = EPS * (Ku_abs + np.abs(f_W)) * rounding_signs(sub.l2g)
    noise_g = EPS * (assembled(Ku_abs) + np.abs(f_g)) * rounding_signs(iface.dofs)
    return eta(rK, r_g) + eta(noise_W, noise_g)


def tied_pieces(topo, gi, active: np.ndarray, rank_of_sub: np.ndarray, size: int) -> list[dict]:
    """Rank 0: per rank, what :func:`distributed_multibody_estimate` needs (computed from the global topology).

    ``gi`` is the :class:`~ddsolve.multibody.GlobalInterface` of ``topo`` and ``active`` its active pairs.
    The tied problem's topology (:func:`ddsolve.multibody.check.tied_scene`, no matrices) has the W layout
    of ``topo``; each rank gets its :class:`~ddsolve.parallel.distribute.TopologySlice` (``"slice"``), the
    tied primal dofs (``"primal_dofs"``, coarse-sized), the floating bodies (``"floating"``) and
    ``"n_bodies"``, and the sharing of its interface dofs in the bodies (``"body"``) and in the tied
    problem (``"tied"``), as :func:`interface_pieces`. (Its W entries on the body interfaces are the
    method's own ``"gi_mask"``.)
    """
    from .distribute import TopologySlice, owned_range, topology

    n_tied, label = tied_nodes(topo, gi, active)
    tied = topology(tied_scene(topo.scene, n_tied, label), "rho", 1.0)
    if not (np.array_equal(tied.sub_of_W, topo.sub_of_W) and np.array_equal(tied.local_index, topo.local_index)):
        raise RuntimeError("the tied topology does not keep the W layout of the bodies")
    primal_dofs = np.unique(tied.l2g[tied.vertex])
    floating = np.asarray(gi.floating_bodies(), dtype=np.int64)
    body, tied_iface = interface_pieces(topo, rank_of_sub, size), interface_pieces(tied, rank_of_sub, size)
    out = []
    for r in range(size):
        lo, hi = owned_range(topo.n_sub, size, r)
        out.append({"slice": TopologySlice.of(tied, lo, hi, primal_dofs.size), "primal_dofs": primal_dofs,
                    "floating": floating, "n_bodies": int(topo.scene.n_bodies),
                    "body": {key: body[r][key] for key in ("interface", "interface_dofs")},
                    "tied": {key: tied_iface[r][key] for key in ("interface", "interface_dofs")}})
    return out


def _tied_rank_substructures(sub, sl):
    """This rank's subdomains (``sub``: same matrices and loads) on the tied layout of the slice ``sl``."""
    from .distribute import W_FIELDS

    tied = copy.copy(sub)
    for name in W_FIELDS:
        setattr(tied, name, getattr(sl, name))
    tied.sub_of_W = sl.sub_of_W - sl.lo
    tied.ndof, tied.body_of_sub, tied.floating_sub = sl.ndof, sl.body_of_sub, sl.floating_sub
    tied.scaling, tied.gamma, tied.primal = sl.scaling, sl.gamma, sl.primal
    tied._edges = tied._primal_space = None
    return tied


def _interface_exchange(sub, comm: CountingComm, piece: dict) -> tuple[InterfaceMap, NeighbourSum]:
    iface = InterfaceMap(sub, sub.interface)
    if not np.array_equal(piece["interface_dofs"], iface.dofs):
        raise RuntimeError("the interface dofs sent by rank 0 are not this rank's")
    return iface, NeighbourSum(comm, piece["interface"])


def distributed_multibody_estimate(sub, u_W: np.ndarray, comm: CountingComm, piece: dict,
                                   gi_mask: np.ndarray) -> tuple[float, int]:
    """The rank's share of :func:`ddsolve.multibody.check.multibody_error_estimate`, the same value on every rank.

    Parameters
    ----------
    sub : RankSubstructures
        This rank's subdomains of the bodies.
    u_W : ndarray, shape (sub.n_W,)
        The solve's W values (copies not yet averaged).
    comm : CountingComm
    piece : dict
        This rank's :func:`tied_pieces`.
    gi_mask : ndarray of bool, shape (sub.n_W,)
        This rank's W entries on the body interfaces (the method's piece).

    Returns
    -------
    estimate : float
    n_factorizations : int
        This rank's (its tied primal-constrained and Dirichlet problems).
    """
    def total(local: float) -> float:
        return comm.allreduce_scalar(float(local))

    if total(0.0 if np.all(np.isfinite(u_W)) else 1.0) > 0:
        return math.inf, 0
    tied = _tied_rank_substructures(sub, piece["slice"])
    iface, body_exchange = _interface_exchange(sub, comm, piece["body"])
    u_body = u_W.copy()                     # the bodies' u: R_D^T u_W in each body (the serial sub.average)
    u_body[iface.entries] = body_exchange.sum(iface.gather(u_W, iface.delta))[iface.position]
    diagonal = sub.K_W.diagonal()           # the copies of a tied node weighted by their diagonals
    # the floating bodies' constants (ddsolve.multibody.check.floating_shifts) from the body-interface
    # entries of all ranks, gathered in rank order (the serial W order): the same k x k solve on every rank
    on = np.flatnonzero(gi_mask)
    body = sub.body_of_sub[sub.sub_of_W]
    rows = comm.allgather((tied.l2g[on], body[on], diagonal[on], diagonal[on] * u_body[on]))
    shift = floating_shifts(*(np.concatenate([r[k] for r in rows]) for k in range(4)), piece["floating"],
                            piece["n_bodies"])
    u_body = u_body + shift[body]
    tiface, tied_exchange = _interface_exchange(tied, comm, piece["tied"])
    u_g = tied_exchange.sum(tiface.gather(diagonal * u_body)) / tied_exchange.sum(tiface.gather(diagonal))
    u_t = u_body.copy()
    u_t[tiface.entries] = u_g[tiface.position]
    cache: dict = {}
    primal_solver = DistributedPrimalSolver(tied, tied.vertex, cache, comm, piece["primal_dofs"])
    schur = DirichletSchur(tied, tied.interface, cache)
    n_fact = primal_solver.n_factorizations + schur.II.n_new_factorizations
    estimate = distributed_error_estimate(tied, u_t, primal_solver, schur, comm, piece["tied"])
    moved = u_body - u_t
    if total(float(np.any(moved))) == 0 or not math.isfinite(estimate):
        return estimate, n_fact
    interior = np.ones(tied.n_W, dtype=bool)
    interior[tiface.entries] = False
    f_g = tied_exchange.sum(tiface.gather(sub.f_W))
    local_max = max(float(np.max(np.abs(sub.f_W[interior]), initial=0.0)), float(np.max(np.abs(f_g), initial=0.0)))
    exponent = int(np.frexp(comm.allreduce_scalar(local_max, op="max"))[1])      # scale-free, as serial
    f_W, u_t, u_g, f_g, moved = (np.ldexp(v, -exponent) for v in (sub.f_W, u_t, u_g, f_g, moved))
    owned = piece["tied"]["interface"].owned
    energy = total(f_W[interior] @ u_t[interior] + f_g[owned] @ u_g[owned])
    if not energy > 0:
        return math.inf, n_fact
    return estimate + math.sqrt(abs(total(moved @ (sub.K_W @ moved))) / energy), n_fact
