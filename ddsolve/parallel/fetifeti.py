"""Distributed FETI-FETI (Section 3.4): the serial :class:`~ddsolve.multibody.fetifeti.FetiFetiSolver` over ranks.

Ownership. The subdomains of all bodies are distributed as for Poisson
(subdomains are numbered body by body, so a rank holds whole bodies or
contiguous parts of them). Rank 0 builds the integer topology and the
:class:`~ddsolve.multibody.GlobalInterface` from the global mesh and sends each
rank its piece (:func:`distribute_fetifeti`); each rank assembles and factors
only its own subdomains.

Multipliers. The global multipliers are the rows of the serial
B = [B_loc; Z B_gl] (same order): the dual jumps inside the bodies, then the
active inter-body pairs, each acting on the designated (first) copies of its
two nodes. A rank holds every row with an entry on one of its subdomains
(:class:`~ddsolve.parallel.fetidp.JumpRows`); F and the preconditioner are the
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

from ..dd.check import needs_check
from ..dd.common import MethodOutput
from ..dd.dual import DUAL_PROJECTIONS, floored_weights
from ..dd.operators import DirichletSchur
from ..errors import InputError
from .check import distributed_multibody_estimate, tied_pieces
from .coarse import DistributedPrimalSolver, pinned_vertices
from .comm import NeighbourSum, shared_indices
from .distribute import owned_range
from .dual import distributed_solve_dual
from .fetidp import JumpRows, jump_pairs, jump_rows, summed_dual_operators
from .setup import RankProblem, gather_solution

__all__ = ["solve_fetifeti_mpi", "distribute_fetifeti", "tilde_pieces"]


def tilde_pieces(topo, spread: np.ndarray, rank_of_sub: np.ndarray, size: int) -> list[dict]:
    """Every rank's share of S~ (:class:`_TildeSchur`), from the global topology (rank 0, at once).

    Parameters
    ----------
    topo : Substructures
        Global topology.
    spread : ndarray of bool, shape (n_W,)
        Primal W entries whose node values are copied to all copies (the primal nodes of the global
        interface; elsewhere the input of S~ is zero on primal entries).
    rank_of_sub : ndarray of int, shape (n_sub,)
    size : int

    Returns
    -------
    list of dict
        Per rank: ``entries`` (its copies, local W positions), ``pos`` (copy -> its local node),
        ``first`` and ``first_pos`` (the designated, first, copy of every node, where the serial S~ puts
        the sum of the copies) and ``shared`` (:class:`SharedIndex` of its nodes).
    """
    all_entries = np.flatnonzero(spread)                                 # sorted: rank by rank
    node_ids, node_index = np.unique(topo.node_of_W[all_entries], return_inverse=True)
    n_nodes = int(node_ids.size)
    first_entry = np.full(n_nodes, np.iinfo(np.int64).max)
    np.minimum.at(first_entry, node_index, all_entries)
    is_first = first_entry[node_index] == all_entries
    sharing = shared_indices(node_index, rank_of_sub[topo.sub_of_W[all_entries]], size, n_nodes)
    w_first = [int(topo.offsets[owned_range(topo.n_sub, size, r)[0]]) for r in range(size)]
    bounds = np.searchsorted(all_entries, w_first + [topo.n_W])
    out = []
    for r, (local_ids, shared) in enumerate(sharing):
        e = slice(bounds[r], bounds[r + 1])
        pos = np.searchsorted(local_ids, node_index[e])
        entries = all_entries[e] - w_first[r]
        out.append({"entries": entries, "pos": pos, "first": entries[is_first[e]], "first_pos": pos[is_first[e]],
                    "shared": shared})
    return out


class _TildeSchur:
    """S~ w of :meth:`FetiFetiSolver._tilde_schur` on this rank's W entries.

    Parameters
    ----------
    schur : DirichletSchur
        On this rank's subdomains, interface = local interface | global interface.
    piece : dict
        This rank's entry of :func:`tilde_pieces`.
    comm : CountingComm
    """

    def __init__(self, schur: DirichletSchur, piece: dict, comm) -> None:
        self.schur = schur
        self.entries, self.pos = piece["entries"], piece["pos"]
        self.first, self.first_pos = piece["first"], piece["first_pos"]
        self.shared = piece["shared"]
        self.exchange = NeighbourSum(comm, self.shared)
        self.n = int(self.shared.n)

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


def distribute_fetifeti(topo, rank_of_sub: np.ndarray, size: int, spec) -> list[dict]:
    """What each rank's FETI-FETI needs from the global topology (computed on rank 0 and sent).

    The global rows are those of the serial B = [B_loc; Z B_gl]: the dual jumps inside the bodies,
    then the active inter-body pairs of ``spec.contact``. Per rank: ``"jump"``
    (:class:`~ddsolve.parallel.fetidp.JumpRows`), per local row ``"col_a"``, ``"col_b"`` (the
    kernel column of the body of each copy, -1 where it does not float) and ``"q"`` (the diagonal
    of Q; None under multiplicity scaling), ``"n_inside"`` (rows inside the bodies, first),
    ``"gi_mask"`` (its W entries on the global interface), ``"tilde"`` (:func:`tilde_pieces`),
    ``"pinned"`` (the pinned coarse dofs, :func:`~ddsolve.parallel.coarse.pinned_vertices`),
    ``"body_col"`` (kernel column of every body, shape (n_bodies,)), ``"n_active"`` and ``"tied"``
    (:func:`~ddsolve.parallel.check.tied_pieces` where rho varies between subdomains, else None).
    """
    from ..multibody import GlobalInterface

    gi = GlobalInterface(topo)
    active = gi.contact_mask(spec.contact)
    floating = gi.floating_bodies()
    primal_dofs = np.unique(topo.l2g[topo.vertex])
    pinned = pinned_vertices(topo, floating, primal_dofs)
    la, lb = jump_pairs(topo, topo.interface & ~topo.vertex)
    ga, gb = gi.pairs[active, 0], gi.pairs[active, 1]
    delta, w = topo.delta, gi.weight
    pa, pb = np.r_[la, ga], np.r_[lb, gb]
    coef_a, coef_b = np.r_[delta[lb], w[gb]], np.r_[-delta[la], -w[ga]]
    sa, sb = topo.sub_of_W[pa], topo.sub_of_W[pb]
    q = (None if topo.scaling == "multiplicity"
         else floored_weights(coef_a ** 2 * topo.rho[sa] + coef_b ** 2 * topo.rho[sb]))
    body_col = np.full(topo.scene.n_bodies, -1)
    body_col[floating] = np.arange(floating.size)
    col_a, col_b = body_col[topo.body_of_sub[sa]], body_col[topo.body_of_sub[sb]]
    tilde = tilde_pieces(topo, topo.vertex & gi.mask, rank_of_sub, size)
    # the final error check (ddsolve.multibody.check) where the coefficient varies between subdomains or the mesh
    # is unstructured (ddsolve.dd.check.needs_check, as serial)
    tied = (tied_pieces(topo, gi, active, rank_of_sub, size)
            if needs_check(topo.rho, spec.mesh != "unstructured", spec.rtol) else [None] * size)
    out = []
    for r, rows in enumerate(jump_rows(pa, pb, coef_a, coef_b, rank_of_sub[sa], rank_of_sub[sb], size)):
        lo, hi = owned_range(topo.n_sub, size, r)
        k = rows.rows
        out.append({"jump": rows, "col_a": col_a[k], "col_b": col_b[k], "q": None if q is None else q[k],
                    "n_inside": int(la.size), "gi_mask": np.array(gi.mask[topo.offsets[lo]:topo.offsets[hi]]),
                    "tilde": tilde[r], "pinned": pinned, "body_col": body_col, "n_active": int(active.sum()),
                    "tied": tied[r]})
    return out


def solve_fetifeti_mpi(prob: RankProblem, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
                       gather: bool = True, projection: str = "weighted") -> tuple[MethodOutput, dict]:
    """FETI-FETI (3.35) on the ranks of ``prob.comm`` for the active set of ``prob.spec.contact``.

    ``projection`` as in :meth:`ddsolve.multibody.fetifeti.FetiFetiSolver.solve`.

    Returns ``(output, info)`` as :func:`ddsolve.parallel.fetidp.solve_fetidp_mpi`; ``output.extra``
    holds ``n_floating_bodies`` and ``n_active``.
    """
    comm, sub = prob.comm, prob.sub
    piece = prob.pieces                                     # from rank 0 (distribute_fetifeti)
    if projection not in DUAL_PROJECTIONS:
        raise InputError("projection", f"unknown projection {projection!r} (choose from {', '.join(DUAL_PROJECTIONS)})")
    t0 = time.perf_counter()
    cache: dict = {}
    primal_solver = DistributedPrimalSolver(sub, sub.vertex, cache, comm, prob.primal_dofs, pinned=piece["pinned"])
    schur = DirichletSchur(sub, sub.interface | piece["gi_mask"], cache)
    tilde = _TildeSchur(schur, piece["tilde"], comm)
    jump: JumpRows = piece["jump"]
    B, B_D = jump.matrices(sub.w0, sub.n_W)
    shared, rows = jump.shared, jump.rows
    exchange = NeighbourSum(comm, shared)
    F, M = summed_dual_operators(B, B_D, primal_solver.solve, tilde.apply, exchange)

    d = exchange.sum(B @ primal_solver.solve(sub.f_W))
    # G = B R: +1 / -1 where the body of the a / b copy floats (zero on the rows inside a body)
    body_col = piece["body_col"]
    k = int((body_col >= 0).sum())
    ca, cb = piece["col_a"], piece["col_b"]
    inter = rows >= piece["n_inside"]
    fa, fb = inter & (ca >= 0), inter & (cb >= 0)
    n_loc = rows.size
    G = e = R_loc = None
    if k:
        r_loc = np.arange(n_loc)
        G = sp.csr_matrix((np.r_[np.ones(fa.sum()), -np.ones(fb.sum())], (np.r_[r_loc[fa], r_loc[fb]],
                                                                          np.r_[ca[fa], cb[fb]])), shape=(n_loc, k))
        col_W = body_col[sub.body_of_sub[sub.sub_of_W]]
        ent = np.flatnonzero(col_W >= 0)
        R_loc = sp.csr_matrix((np.ones(ent.size), (ent, col_W[ent])), shape=(sub.n_W, k))
        e = comm.allreduce_sum(R_loc.T @ sub.f_W)
    q = piece["q"] if projection != "orthogonal" else None      # Q of ddsolve.dd.dual.projection_weights
    setup = time.perf_counter() - t0
    mpi_at_setup = comm.counters.seconds          # the solve's MPI time starts here
    sol = distributed_solve_dual(F, M, d, G, e, q, comm=comm, owned=shared.owned, rtol=rtol, maxiter=maxiter,
                                 cond=cond)
    u_W = primal_solver.solve(sub.f_W - B.T @ sol.lam)
    if sol.alpha is not None:
        u_W = u_W + R_loc @ sol.alpha
    u = gather_solution(prob, u_W) if gather else None
    extra = {"n_floating_bodies": k, "n_active": piece["n_active"]}
    n_fact = primal_solver.n_factorizations + schur.II.n_new_factorizations
    if sol.krylov.converged and piece["tied"] is not None:     # as serial: the error of u itself
        extra["error_estimate"], n_check = distributed_multibody_estimate(
            sub, u_W, comm, piece["tied"], piece["gi_mask"])
        n_fact += n_check
    out = MethodOutput(u=u, krylov=sol.krylov, nlambda=jump.n_lambda, n_factorizations=n_fact,
                       setup_seconds=setup, extra=extra)
    info = {"mpi_at_setup": mpi_at_setup,
            "coarse_seconds": primal_solver.coarse_seconds + sol.coarse_seconds,
            "krylov_seconds": sol.krylov_seconds, "per_iteration": sol.per_iteration}
    return out, info
