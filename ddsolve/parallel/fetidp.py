"""Distributed FETI-DP (Section 2.6): the serial operators on each rank, multipliers shared.

Multipliers. The global multipliers are the rows of the serial fully
redundant jump operator B on the dual nodes (same order). A rank holds every
multiplier that touches one of its subdomains; a multiplier between two
subdomains of different ranks is held by both (the lower rank owns it for
inner products). With the rank-local B_loc (its columns: the owned W entries),

    F lambda = sum_ranks B_loc A~_loc^{-1} B_loc^T lambda_loc,

i.e. local F and one :class:`~ddsolve.parallel.comm.NeighbourSum` of the
partial values of the shared multipliers; the same for the Dirichlet
preconditioner B_D S B_D^T. A~^{-1} needs one Allreduce of the primal
right-hand side (:class:`~ddsolve.parallel.coarse.DistributedPrimalSolver`).
Per iteration: 2 neighbour exchanges, 4 Allreduces (3 of PCG, 1 coarse).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..dd.common import MethodOutput
from ..dd.dual import dual_operators
from ..dd.fetidp import dual_solve
from ..dd.operators import DirichletSchur, linear_operator
from ..krylov import KrylovResult
from .check import distributed_error_estimate, distributed_needs_check, interface_pieces
from .coarse import DistributedPrimalSolver
from .comm import NeighbourSum, SharedIndex, shared_indices
from .krylov import distributed_pcg
from .setup import RankProblem, gather_solution

__all__ = ["solve_fetidp_mpi", "distribute_fetidp", "JumpRows", "jump_rows"]


@dataclass
class JumpRows:
    """One rank's rows of a jump operator given by pairs of global W entries.

    Row k of the global operators: B = e_pa[k] - e_pb[k], B_D = coef_a[k] e_pa[k] + coef_b[k] e_pb[k].
    A rank holds the rows with an entry on one of its subdomains (both ranks of a row between two).

    Attributes
    ----------
    pa, pb : ndarray of int, shape (n_local,)
        Global W entries of the two copies of each local row.
    coef_a, coef_b : ndarray, shape (n_local,)
        Their entries in B_D.
    a_mine, b_mine : ndarray of bool, shape (n_local,)
        Whether the copy lies on this rank's subdomains.
    rows : ndarray of int, shape (n_local,)
        Global row numbers (sorted).
    shared : SharedIndex
    n_lambda : int
        Number of global rows.
    """

    pa: np.ndarray
    pb: np.ndarray
    coef_a: np.ndarray
    coef_b: np.ndarray
    a_mine: np.ndarray
    b_mine: np.ndarray
    rows: np.ndarray
    shared: SharedIndex
    n_lambda: int

    def matrices(self, w0: int, n_W: int) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """B_loc, B_D_loc, shape (n_local, n_W): the columns are the rank's W entries w0..w0+n_W-1."""
        k = np.arange(self.rows.size)
        a, b = self.a_mine, self.b_mine
        r_idx = np.r_[k[a], k[b]]
        c_idx = np.r_[self.pa[a], self.pb[b]] - w0
        shape = (self.rows.size, n_W)
        B = sp.csr_matrix((np.r_[np.ones(a.sum()), -np.ones(b.sum())], (r_idx, c_idx)), shape=shape)
        B_D = sp.csr_matrix((np.r_[self.coef_a[a], self.coef_b[b]], (r_idx, c_idx)), shape=shape)
        return B, B_D


def jump_rows(pa: np.ndarray, pb: np.ndarray, coef_a: np.ndarray, coef_b: np.ndarray, ra: np.ndarray,
              rb: np.ndarray, size: int) -> list[JumpRows]:
    """The :class:`JumpRows` of every rank at once, O(n_lambda log n_lambda).

    Parameters
    ----------
    pa, pb : ndarray of int, shape (n_lambda,)
        Global W entries of the two copies of every row.
    coef_a, coef_b : ndarray, shape (n_lambda,)
        Entries of B_D.
    ra, rb : ndarray of int, shape (n_lambda,)
        Ranks owning the W entries pa and pb.
    size : int
    """
    n_lam = pa.size
    rows_all = np.arange(n_lam)
    out = []
    for q, (rows, shared) in enumerate(shared_indices(np.r_[rows_all, rows_all], np.r_[ra, rb], size, n_lam)):
        out.append(JumpRows(pa=pa[rows], pb=pb[rows], coef_a=coef_a[rows], coef_b=coef_b[rows],
                            a_mine=ra[rows] == q, b_mine=rb[rows] == q, rows=rows, shared=shared, n_lambda=n_lam))
    return out


def jump_pairs(topo, mask_global: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global W entries (pa, pb) of the +1 and -1 copies of every row of ``topo.jump_operators(mask)``."""
    B, _ = topo.jump_operators(mask_global)
    n_lam = B.shape[0]
    coo = B.tocoo()
    pa = np.empty(n_lam, dtype=np.int64)
    pb = np.empty(n_lam, dtype=np.int64)
    pa[coo.row[coo.data > 0]] = coo.col[coo.data > 0]
    pb[coo.row[coo.data < 0]] = coo.col[coo.data < 0]
    return pa, pb


def distribute_fetidp(topo, rank_of_sub: np.ndarray, size: int, spec=None) -> list[dict]:
    """What each rank's FETI-DP needs from the global topology (computed on rank 0 and sent).

    Returns, per rank, ``{"jump": JumpRows, "interface": ..., "interface_dofs": ...}``: its rows of the
    serial fully redundant B on the dual nodes (``topo.interface & ~topo.vertex``), B_D scaled by
    delta-dagger, and the sharing of its interface dofs for the final error check
    (:func:`ddsolve.parallel.check.interface_pieces`).
    """
    pa, pb = jump_pairs(topo, topo.interface & ~topo.vertex)
    delta = topo.delta
    ra, rb = rank_of_sub[topo.sub_of_W[pa]], rank_of_sub[topo.sub_of_W[pb]]
    rows = jump_rows(pa, pb, delta[pb], -delta[pa], ra, rb, size)
    return [{"jump": r, **iface} for r, iface in zip(rows, interface_pieces(topo, rank_of_sub, size))]


def summed_dual_operators(B, B_D, solve, schur_matvec, exchange: NeighbourSum):
    """F and M^{-1} of :func:`ddsolve.dd.dual.dual_operators` on this rank's multipliers, each
    followed by the neighbour sum of the rows shared with other ranks; shapes (n,) -> (n,)."""
    F_loc, M_loc = dual_operators(B, B_D, solve, schur_matvec)

    def F(lam: np.ndarray) -> np.ndarray:
        return exchange.sum(F_loc(lam))

    def M(lam: np.ndarray) -> np.ndarray:
        return exchange.sum(M_loc(lam))

    return F, M


def solve_fetidp_mpi(prob: RankProblem, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
                     gather: bool = True) -> tuple[MethodOutput, dict]:
    """FETI-DP on the ranks of ``prob.comm``; the serial :func:`ddsolve.dd.solve_fetidp`, distributed.

    Returns
    -------
    output : MethodOutput
        ``u`` is the global solution on rank 0 when ``gather`` (None elsewhere);
        ``krylov.x`` is this rank's multipliers.
    info : dict
        ``coarse_seconds``, ``per_iteration`` (messages, bytes, allreduces of this rank
        per Krylov iteration), ``krylov_seconds``.
    """
    comm, sub = prob.comm, prob.sub
    t0 = time.perf_counter()
    cache: dict = {}
    jump: JumpRows = prob.pieces["jump"]                    # from rank 0 (distribute_fetidp)
    B, B_D = jump.matrices(sub.w0, sub.n_W)
    shared, n_lam = jump.shared, jump.n_lambda
    primal_solver = DistributedPrimalSolver(sub, sub.vertex, cache, comm, prob.primal_dofs)
    primal_solver.assemble_basis()                      # in the setup, not in the first solve
    schur = DirichletSchur(sub, sub.interface, cache)
    schur.explicit                                      # decided (dense blocks formed) in the setup
    exchange = NeighbourSum(comm, shared)
    F, M = summed_dual_operators(B, B_D, dual_solve(primal_solver, B), schur.matvec, exchange)
    d = exchange.sum(B @ primal_solver.solve(sub.f_W))
    setup = time.perf_counter() - t0
    mpi_at_setup = comm.counters.seconds          # the solve's MPI time starts here
    n = shared.n
    t1 = time.perf_counter()
    if n_lam == 0:          # every interface node primal (a tiny mesh): A~ is the assembled matrix, as serial
        kr = KrylovResult.solved_directly(n)
        per_iteration = (0.0, 0.0, 0.0)
    else:
        kr, per_iteration = distributed_pcg(linear_operator(n, F), d, comm=comm, owned=shared.owned,
                                            rtol=rtol, maxiter=maxiter, M=linear_operator(n, M), cond=cond)
    krylov_seconds = time.perf_counter() - t1
    u_W = primal_solver.solve(sub.f_W - B.T @ kr.x)
    u = gather_solution(prob, u_W) if gather else None
    extra = {"n_primal": primal_solver.n_primal}
    # as serial: the dual rule bounds the jump B u, not the error of u (ddsolve.dd.check)
    if kr.converged and distributed_needs_check(sub, comm, rtol):
        extra["error_estimate"] = distributed_error_estimate(sub, u_W, primal_solver, schur, comm, prob.pieces)
    out = MethodOutput(u=u, krylov=kr, nlambda=n_lam,
                       n_factorizations=primal_solver.n_factorizations + schur.II.n_new_factorizations,
                       setup_seconds=setup, extra=extra)
    info = {"mpi_at_setup": mpi_at_setup,
            "coarse_seconds": primal_solver.coarse_seconds, "krylov_seconds": krylov_seconds,
            "per_iteration": per_iteration}
    return out, info
