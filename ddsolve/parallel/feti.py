"""Distributed one-level FETI (Section 2.5): projected PCG with the natural coarse space over ranks.

The multipliers are distributed as in :mod:`ddsolve.parallel.fetidp` (all
interface nodes instead of the dual ones). The natural coarse space G = B R
(R: constants on the floating subdomains, one column each, numbered
globally) is known row by row on every rank that holds the row (its two
entries come from the subdomains of the row's two copies, which rank 0 sends
with the rows, :func:`distribute_feti`: no communication in the solve).
The projection (Q-weighted with rho-scaling, as in :func:`ddsolve.dd.dual.solve_dual`)

    P v = v - G_s (G_s^T G_s)^{-1} G_s^T v,   G_s = Q^{1/2} G,

needs G_s^T v: a sum over all multipliers, i.e. the owned rows of every rank
and one Allreduce of k doubles (k floating subdomains); G_s^T G_s is
assembled once (allgather of COO triplets) and factored redundantly on every
rank, like the FETI-DP coarse problem. Per iteration: 2 neighbour exchanges
(F, M), 5 Allreduces (3 of PCG, 2 projections).
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..dd.common import MethodOutput
from ..dd.dual import floored_weights
from ..dd.feti import pinned_entries
from ..dd.local import BatchedSolver
from ..dd.operators import DirichletSchur
from .check import distributed_error_estimate, distributed_needs_check, interface_pieces
from .coarse import DistributedPrimalSolver
from .comm import NeighbourSum
from .dual import DistributedProjection, distributed_solve_dual
from .fetidp import JumpRows, jump_pairs, jump_rows, summed_dual_operators
from .setup import RankProblem, gather_solution

__all__ = ["DistributedProjection", "solve_feti_mpi", "distribute_feti"]   # DistributedProjection lives in .dual


def distribute_feti(topo, rank_of_sub: np.ndarray, size: int, spec=None) -> list[dict]:
    """What each rank's one-level FETI needs from the global topology (computed on rank 0 and sent).

    Returns, per rank, a dict with ``"jump"`` (:class:`~ddsolve.parallel.fetidp.JumpRows`: its
    rows of the fully redundant B on every interface node, B_D scaled by delta-dagger), per
    local row ``"sub_a"``, ``"sub_b"`` (the global subdomains of its two copies) and ``"q"``
    (the diagonal of Q, delta_b^2 rho_a + delta_a^2 rho_b as in :func:`ddsolve.dd.feti.solve_feti`;
    None under multiplicity scaling), and the subdomain-level ``"floating_sub"`` and
    ``"sub_size"`` (W entries per subdomain), shape (n_sub,).
    """
    pa, pb = jump_pairs(topo, np.ones(topo.n_W, dtype=bool))
    delta, rho = topo.delta, topo.rho
    sa, sb = topo.sub_of_W[pa], topo.sub_of_W[pb]
    q = None if topo.scaling == "multiplicity" else floored_weights(delta[pb] ** 2 * rho[sa] + delta[pa] ** 2 * rho[sb])
    sub_size = np.diff(topo.offsets).astype(float)
    floating = np.asarray(topo.floating_sub)
    out = []
    pieces = interface_pieces(topo, rank_of_sub, size)      # for the final error check
    for rows, iface in zip(jump_rows(pa, pb, delta[pb], -delta[pa], rank_of_sub[sa], rank_of_sub[sb], size),
                           pieces):
        r = rows.rows
        out.append({"jump": rows, "sub_a": sa[r], "sub_b": sb[r], "q": None if q is None else q[r],
                    "floating_sub": floating, "sub_size": sub_size, **iface})
    return out


def solve_feti_mpi(prob: RankProblem, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
                   gather: bool = True, projection: str = "weighted") -> tuple[MethodOutput, dict]:
    """One-level FETI on the ranks of ``prob.comm``; the serial :func:`ddsolve.dd.solve_feti`, distributed.

    ``projection``: ``"weighted"`` (Q-weighted under rho-scaling) or ``"orthogonal"`` (Q = I, the
    thesis preset), as in the serial solver.

    Returns ``(output, info)`` as :func:`ddsolve.parallel.fetidp.solve_fetidp_mpi`.
    """
    comm, sub = prob.comm, prob.sub
    t0 = time.perf_counter()
    cache: dict = {}
    piece = prob.pieces                                     # from rank 0 (distribute_feti)
    jump: JumpRows = piece["jump"]
    B, B_D = jump.matrices(sub.w0, sub.n_W)
    shared, n_lam = jump.shared, jump.n_lambda
    fixed = pinned_entries(sub)
    Kplus = BatchedSolver(sub, ~fixed, cache)
    schur = DirichletSchur(sub, sub.interface, cache)
    exchange = NeighbourSum(comm, shared)
    F, M = summed_dual_operators(B, B_D, Kplus.solve, schur.matvec, exchange)

    F_d = exchange.sum(B @ Kplus.solve(sub.f_W))
    n_fact = Kplus.n_new_factorizations + schur.II.n_new_factorizations
    # global numbering of the floating subdomains; G = B R row by row from the two copies of each multiplier
    floating = piece["floating_sub"]
    col_of_sub = np.full(prob.n_sub, -1)
    col_of_sub[floating] = np.arange(int(floating.sum()))
    k = int(floating.sum())
    size = piece["sub_size"]
    sa, sb = piece["sub_a"], piece["sub_b"]
    n_loc = shared.n
    rows = np.arange(n_loc)
    fa, fb = floating[sa], floating[sb]
    G = sp.csr_matrix((np.r_[1.0 / np.sqrt(size[sa[fa]]), -1.0 / np.sqrt(size[sb[fb]])],
                       (np.r_[rows[fa], rows[fb]], np.r_[col_of_sub[sa[fa]], col_of_sub[sb[fb]]])),
                      shape=(n_loc, k))
    R_loc = None
    e = None
    if k:
        ent = np.flatnonzero(sub.floating_sub[sub.sub_of_W])
        R_loc = sp.csr_matrix((1.0 / np.sqrt(np.diff(sub.offsets)[sub.sub_of_W[ent]]),
                               (ent, col_of_sub[sub.lo + sub.sub_of_W[ent]])), shape=(sub.n_W, k))
        e = comm.allreduce_sum(R_loc.T @ sub.f_W)
        n_fact += 1
    q = piece["q"] if projection != "orthogonal" else None
    setup = time.perf_counter() - t0
    mpi_at_setup = comm.counters.seconds          # the solve's MPI time starts here
    sol = distributed_solve_dual(F, M, F_d, G if k else None, e, q, comm=comm, owned=shared.owned, rtol=rtol,
                                 maxiter=maxiter, cond=cond, n_global=n_lam)
    kr = sol.krylov
    u_W = Kplus.solve(sub.f_W - B.T @ sol.lam)
    if sol.alpha is not None:
        u_W = u_W + R_loc @ sol.alpha
    u = gather_solution(prob, u_W) if gather else None
    extra = {"n_floating": k}
    # as serial: the dual rule bounds the jump B u, not the error of u (FETI: one more factorization)
    if kr.converged and distributed_needs_check(sub, comm, rtol):
        primal_solver = DistributedPrimalSolver(sub, sub.vertex, cache, comm, prob.primal_dofs)
        extra["error_estimate"] = distributed_error_estimate(sub, u_W, primal_solver, schur, comm, prob.pieces)
        n_fact += primal_solver.n_factorizations
    out = MethodOutput(u=u, krylov=kr, nlambda=n_lam, n_factorizations=n_fact, setup_seconds=setup,
                       extra=extra)
    info = {"mpi_at_setup": mpi_at_setup,
            "coarse_seconds": sol.coarse_seconds, "krylov_seconds": sol.krylov_seconds,
            "per_iteration": sol.per_iteration}
    return out, info
