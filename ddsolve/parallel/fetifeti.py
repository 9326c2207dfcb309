"""Distributed FETI-FETI (Section 3.4): the serial :class:`~ddsolve.multibody.fetifeti.FetiFetiSolver` over ranks.

Ownership. The subdomains of all bodies are distributed as for Poisson
(subdomains are numbered body by body, so a rank holds whole bodies or
contiguous parts of them). Every rank builds the integer topology and the
:class:`~ddsolve.multibody.GlobalInterface` from the global mesh (replicated,
no communication) and assembles and factors only its own subdomains.

Multipliers. The global multipliers are the rows of the serial
B = [B_loc; Z B_gl] (same order): the dual jumps inside the bodies, then the
active inter-body pairs, each acting on the designated (first) copies of its
two nodes. A rank holds every row with an entry on one of its subdomains
(:func:`~ddsolve.parallel.fetidp.pair_rows`); F and the preconditioner are the
local operators followed by one neighbour sum.

A~^+ (2.17) with one pinned primal vertex per floating body: the
primal-constrained solve with its coarse problem summed over ranks and
factored redundantly (:class:`~ddsolve.parallel.coarse.DistributedPrimalSolver`);
the pinned coarse dofs are chosen from the global topology (the first primal
W entry of each floating body, as in serial), the same on every rank.

S~ of the preconditioner copies the value of a primal node on the global
interface (held at its designated copy) to all its subdomain copies, applies
S and sums the copies back. The copies of such a node may lie on several
ranks: the copy and the sum are one neighbour sum each over the shared primal
nodes of the global interface (:meth:`_TildeSchur.apply`).

Natural coarse space. G = Z B_gl R (R: constants on each floating body; the
rows of B_loc vanish on R) is known row by row where the row lives; G^T v is
one Allreduce of k doubles (k floating bodies) and G^T Q G is summed once
and factored redundantly on every rank (:mod:`ddsolve.parallel.dual`): k is
the number of floating bodies (a few), every rank needs all of alpha, and a
solve on one rank would add a gather and a broadcast, two latency-bound steps,
per projection on the critical path.

Per iteration (P >= 2): 4 neighbour exchanges (F, M and the two of S~),
5 Allreduces with floating bodies (3 of PCG, 2 projections; 1 more per coarse
right-hand side of A~^+).
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..dd.common import MethodOutput
from ..dd.dual import DUAL_PROJECTIONS
from ..dd.operators import DirichletSchur
from .coarse import DistributedPrimalSolver, pinned_vertices
from .comm import NeighbourSum, SharedIndex
from .dual import distributed_solve_dual
from .fetidp import jump_pairs, pair_rows, summed_dual_operators
from .setup import RankProblem, gather_solution

__all__ = ["solve_fetifeti_mpi"]


class _TildeSchur:
    """S~ w of :meth:`FetiFetiSolver._tilde_schur` on this rank's W entries.

    Parameters
    ----------
    prob : RankProblem
    schur : DirichletSchur
        On this rank's subdomains, interface = local interface | global interface.
    spread : ndarray of bool, shape (n_W_global,)
        Primal W entries whose node values are copied to all copies (the primal nodes of
        the global interface; elsewhere the input of S~ is zero on primal entries).
    """

    def __init__(self, prob: RankProblem, schur: DirichletSchur, spread: np.ndarray) -> None:
        topo, sub, comm = prob.topo, prob.sub, prob.comm
        self.schur = schur
        node_ids = np.unique(topo.node_of_W[spread])                     # global numbering of the nodes
        sl = slice(sub.w0, sub.w1)
        self.entries = np.flatnonzero(spread[sl])                        # local copies
        local_node = np.searchsorted(node_ids, topo.node_of_W[sl][self.entries])
        self.local_ids = np.unique(local_node)
        self.pos = np.searchsorted(self.local_ids, local_node)           # copy -> local node index
        all_entries = np.flatnonzero(spread)
        self.shared = SharedIndex.build(comm.rank, self.local_ids,
                                        np.searchsorted(node_ids, topo.node_of_W[all_entries]),
                                        prob.rank_of_sub[topo.sub_of_W[all_entries]], int(node_ids.size))
        self.exchange = NeighbourSum(comm, self.shared)
        # the designated (first) copy of every node, where the serial S~ puts the sum of the copies
        first = np.full(topo.scene.n_nodes, np.iinfo(np.int64).max)
        np.minimum.at(first, topo.node_of_W[all_entries], all_entries)
        self.first = self.entries[first[topo.node_of_W[sl][self.entries]] == sub.w0 + self.entries]
        self.first_pos = self.pos[np.isin(self.entries, self.first)]
        self.n = int(self.local_ids.size)

    def apply(self, w: np.ndarray) -> np.ndarray:
        """S~ w: spread the node values to every copy, S, sum the copies to the first copy (n_W,) -> (n_W,)."""
        node = self.exchange.sum(np.bincount(self.pos, weights=w[self.entries], minlength=self.n))
        x = w.copy()
        x[self.entries] = node[self.pos]
        y = self.schur.matvec(x)
        total = self.exchange.sum(np.bincount(self.pos, weights=y[self.entries], minlength=self.n))
        y[self.entries] = 0.0
        y[self.first] = total[self.first_pos]
        return y


def solve_fetifeti_mpi(prob: RankProblem, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
                       gather: bool = True, projection: str = "weighted") -> tuple[MethodOutput, dict]:
    """FETI-FETI (3.35) on the ranks of ``prob.comm`` for the active set of ``prob.spec.contact``.

    ``projection`` as in :meth:`ddsolve.multibody.fetifeti.FetiFetiSolver.solve`.

    Returns ``(output, info)`` as :func:`ddsolve.parallel.fetidp.solve_fetidp_mpi`; ``output.extra``
    holds ``n_floating_bodies`` and ``n_active``.
    """
    comm, sub, topo, gi = prob.comm, prob.sub, prob.topo, prob.gi
    t0 = time.perf_counter()
    active = gi.contact_mask(prob.spec.contact)
    floating = gi.floating_bodies()
    cache: dict = {}
    primal_dofs = np.unique(topo.l2g[topo.vertex])
    body_W = topo.body_of_sub[topo.sub_of_W]
    primal_solver = DistributedPrimalSolver(sub, sub.vertex, cache, comm, primal_dofs,
                                            pinned=pinned_vertices(topo, floating, primal_dofs))
    sl = slice(sub.w0, sub.w1)
    schur = DirichletSchur(sub, sub.interface | gi.mask[sl], cache)
    tilde = _TildeSchur(prob, schur, topo.vertex & gi.mask)
    # global rows: B_loc (dual jumps inside the bodies), then the active inter-body pairs
    la, lb = jump_pairs(topo, topo.interface & ~topo.vertex)
    ga, gb = gi.pairs[active, 0], gi.pairs[active, 1]
    delta, w = topo.delta, gi.weight
    pa, pb = np.r_[la, ga], np.r_[lb, gb]
    coef_a, coef_b = np.r_[delta[lb], w[gb]], np.r_[-delta[la], -w[ga]]
    B, B_D, shared, rows = pair_rows(prob, pa, pb, coef_a, coef_b)
    exchange = NeighbourSum(comm, shared)
    F, M = summed_dual_operators(B, B_D, primal_solver.solve, tilde.apply, exchange)

    d = exchange.sum(B @ primal_solver.solve(sub.f_W))
    # G = B R: +1 / -1 where the body of the a / b copy floats (zero on the rows inside a body)
    k = int(floating.size)
    col = np.full(topo.scene.n_bodies, -1)
    col[floating] = np.arange(k)
    ca, cb = col[body_W[pa[rows]]], col[body_W[pb[rows]]]
    inter = rows >= la.size
    fa, fb = inter & (ca >= 0), inter & (cb >= 0)
    n_loc = rows.size
    G = e = R_loc = None
    if k:
        r_loc = np.arange(n_loc)
        G = sp.csr_matrix((np.r_[np.ones(fa.sum()), -np.ones(fb.sum())], (np.r_[r_loc[fa], r_loc[fb]],
                                                                          np.r_[ca[fa], cb[fb]])), shape=(n_loc, k))
        ent = np.flatnonzero(col[body_W[sl]] >= 0)
        R_loc = sp.csr_matrix((np.ones(ent.size), (ent, col[body_W[sl]][ent])), shape=(sub.n_W, k))
        e = comm.allreduce_sum(R_loc.T @ sub.f_W)
    if projection not in DUAL_PROJECTIONS:
        raise ValueError(f"unknown projection {projection!r} (choose from {', '.join(DUAL_PROJECTIONS)})")
    q = None                                 # Q of ddsolve.dd.dual.projection_weights on the local rows
    if projection != "orthogonal" and topo.scaling != "multiplicity":
        rho = topo.rho
        q = coef_a[rows] ** 2 * rho[topo.sub_of_W[pa[rows]]] + coef_b[rows] ** 2 * rho[topo.sub_of_W[pb[rows]]]
    setup = time.perf_counter() - t0
    sol = distributed_solve_dual(F, M, d, G, e, q, comm=comm, owned=shared.owned, rtol=rtol, maxiter=maxiter,
                                 cond=cond)
    u_W = primal_solver.solve(sub.f_W - B.T @ sol.lam)
    if sol.alpha is not None:
        u_W = u_W + R_loc @ sol.alpha
    u = gather_solution(prob, u_W) if gather else None
    out = MethodOutput(u=u, krylov=sol.krylov, nlambda=int(pa.size),
                       n_factorizations=primal_solver.n_factorizations + schur.II.n_new_factorizations,
                       setup_seconds=setup,
                       extra={"n_floating_bodies": k, "n_active": int(active.sum())})
    info = {"coarse_seconds": primal_solver.coarse_seconds + sol.coarse_seconds,
            "krylov_seconds": sol.krylov_seconds, "per_iteration": sol.per_iteration}
    return out, info
