"""Distributed hybrid method (Section 4.2): :class:`~ddsolve.multibody.hybrid.HybridSolver` over ranks.

Unknowns. u_Gamma (one value per global dof of the body interfaces) is held
by every rank with a subdomain copy of the dof, with consistent copies
(:class:`DistributedSpace`, as the interface dofs of the distributed BDDC);
the lowest such rank owns it for inner products. The active multipliers
(pairs of dofs of two bodies) are held by every rank that holds one of the
pair's two dofs (:class:`DistributedActiveSet`).

Operators. S^_c, M_BDDC (A~^+ of every body, floating bodies pinned) and the
inexact S~_OL of (4.9)-(4.10) are the serial subdomain operators followed by
one neighbour sum on their output space (S~_OL: three, on Gamma_0, Gamma_0 and
Gamma_OL). The jump Z B^ u needs one neighbour sum of the multipliers (each
dof contributes on its owner rank); its transpose needs none (every holder of
a dof holds every multiplier that touches it). The two primal-constrained
solvers sum their coarse right-hand sides with one Allreduce each
(:class:`~ddsolve.parallel.coarse.DistributedPrimalSolver`).

Coarse problems of the floating bodies. P_R (the mean on each floating
body) is one Allreduce of k doubles; the projection P^k = I - G (G^T G)^{-1}
G^T of G^k = Z B^ R_c is :class:`~ddsolve.parallel.dual.DistributedProjection`:
G^T G (k x k) summed once and factored redundantly, G^T v one Allreduce of k
doubles. The preconditioner (4.11) applies P_R and P^k to the two blocks of the
same vector, before and after its solves: each such pair is one Allreduce of
2 k doubles (:meth:`DistributedHybrid.P_R_and_project`); so are the two P^k of
the operator (4.13), on its input multipliers and on the jump of its u_Gamma. PCR is the serial
recurrence with global reductions (:class:`~ddsolve.parallel.krylov.DistributedPCR`),
restarted as in serial.

Only the orthogonal projection P^k (the default and the thesis's) is
distributed; ``projection="dirichlet"``/``"lumped"`` are refused under mpiexec.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..dd.check import needs_check
from ..dd.common import MethodOutput
from ..dd.operators import DirichletSchur, linear_operator
from ..errors import InputError
from ..krylov.result import KrylovResult
from ..multibody.fallback import with_s_ol_fallback
from ..multibody.hybrid import NO_COND_MESSAGE, S_OL_FORMS, InterfaceSpace
from ..multibody.kernel import FloatingSums
from .check import distributed_multibody_estimate, tied_pieces
from .coarse import DistributedPrimalSolver, pinned_vertices
from .comm import NeighbourSum, SharedIndex, shared_indices
from .distribute import owned_range
from .dual import DistributedProjection
from .krylov import DistributedPCR, IterationCounter, Reductions
from .setup import RankProblem, gather_solution

log = logging.getLogger(__name__)

__all__ = ["DistributedActiveSet", "DistributedHybrid", "DistributedSpace", "distribute_hybrid", "solve_hybrid_mpi"]


class DistributedSpace:
    """This rank's part of a space of continuous interface values, and its sharing.

    Parameters
    ----------
    sub : RankSubstructures
    mask : ndarray of bool, shape (sub.n_W,)
        This rank's W entries of the space.
    sharing : tuple (dofs, SharedIndex, n_global)
        From rank 0 (:func:`distribute_hybrid`): the sorted global dofs this rank holds (checked
        against ``space.dofs``), their sharing and the number of global dofs of the space.
    comm : CountingComm

    Attributes
    ----------
    space : InterfaceSpace
        On this rank's W entries; ``space.dofs`` the sorted global dofs it holds.
    shared : SharedIndex
    exchange : NeighbourSum
    owned : ndarray of bool, shape (n,)
    n : int
    n_global : int
    """

    def __init__(self, sub, mask: np.ndarray, sharing: tuple, comm) -> None:
        self.space = InterfaceSpace(sub, mask)
        dofs, self.shared, n_global = sharing
        if not np.array_equal(dofs, self.space.dofs):
            raise RuntimeError("the interface dofs sent by rank 0 are not this rank's")
        self.exchange = NeighbourSum(comm, self.shared)
        self.owned = self.shared.owned
        self.n = self.space.n
        self.n_global = int(n_global)

    def local_index(self, dofs: np.ndarray) -> np.ndarray:
        """Local index of global ``dofs`` in this space, -1 where this rank does not hold them."""
        if self.n == 0:
            return np.full(dofs.shape, -1, dtype=np.int64)
        pos = np.minimum(np.searchsorted(self.space.dofs, dofs), self.n - 1)
        return np.where(self.space.dofs[pos] == dofs, pos, -1)


def distribute_hybrid(topo, rank_of_sub: np.ndarray, size: int, spec=None) -> list[dict]:
    """What each rank's hybrid method (and active set method) needs from the global topology.

    Computed on rank 0 and sent (:mod:`ddsolve.parallel.setup`). Per rank:

    * ``"gi_mask"``: its W entries on the global interface, shape (sub.n_W,);
    * ``"spaces"``: for ``"gamma"`` (u_Gamma: every interface), ``"glob"`` (Gamma_OL) and ``"loc"``
      (Gamma_0), the (dofs, SharedIndex, n_global) of :class:`DistributedSpace`;
    * ``"pinned"``, ``"local_primal"``: the pinned coarse dofs of the floating bodies and the primal
      dofs off the global interface (coarse-sized);
    * the replicated data of the global interface (its size, not that of all dofs):
      ``"floating"``, ``"n_bodies"``, ``"pair_dofs"``, ``"pair_weight"``, ``"pair_body"`` (n_gl, 2),
      ``"inc_dof"``, ``"inc_rank"`` (the (dof, rank) incidences of its dofs, sorted),
      ``"contact_mask"`` (multibody: the active pairs of ``spec.contact``; contact: None) and
      ``"gamma_dofs"`` (the global u_Gamma numbering of the replicated active set loop);
    * ``"tied"``: :func:`~ddsolve.parallel.check.tied_pieces` for the final error check of a multibody
      solve where rho varies between subdomains, else None.
    """
    from ..multibody import GlobalInterface

    gi = GlobalInterface(topo)
    gamma_mask = topo.interface | gi.mask
    floating = np.asarray(gi.floating_bodies(), dtype=np.int64)
    primal_dofs = np.unique(topo.l2g[topo.vertex])
    spaces = {}
    for name, mask in (("gamma", gamma_mask), ("glob", gi.mask), ("loc", topo.interface & ~gi.mask)):
        ent = np.flatnonzero(mask)
        gid = topo.l2g[ent]
        n_global = int(np.unique(gid).size)
        spaces[name] = [(dofs, shared, n_global)
                        for dofs, shared in shared_indices(gid, rank_of_sub[topo.sub_of_W[ent]], size, topo.ndof)]
    ent = np.flatnonzero(gi.mask)
    inc_dof, inc_rank = np.divmod(np.unique(topo.l2g[ent].astype(np.int64) * size
                                            + rank_of_sub[topo.sub_of_W[ent]]), size)
    common = {"pinned": pinned_vertices(topo, floating, primal_dofs),
              "local_primal": np.unique(topo.l2g[topo.vertex & ~gi.mask]), "floating": floating,
              "n_bodies": int(topo.scene.n_bodies), "pair_dofs": topo.dof_of_node[gi.pair_nodes],
              "pair_weight": gi.weight[gi.pairs], "pair_body": topo.body_of_sub[topo.sub_of_W[gi.pairs]],
              "inc_dof": inc_dof, "inc_rank": inc_rank,
              "contact_mask": gi.contact_mask(spec.contact) if spec is not None and spec.problem == "multibody"
              else None,
              "gamma_dofs": np.unique(topo.l2g[gamma_mask]) if spec is not None and spec.problem == "contact"
              else None}
    tied = [None] * size              # the final error check of a multibody solve (ddsolve.multibody.check)
    if common["contact_mask"] is not None and needs_check(topo.rho, spec.mesh != "unstructured", spec.rtol):
        tied = tied_pieces(topo, gi, common["contact_mask"], rank_of_sub, size)
    out = []
    for r in range(size):
        lo, hi = owned_range(topo.n_sub, size, r)
        out.append({**common, "gi_mask": np.array(gi.mask[topo.offsets[lo]:topo.offsets[hi]]),
                    "spaces": {name: spaces[name][r] for name in spaces}, "tied": tied[r]})
    return out


class _LocalPairs:
    """Rows of a jump operator between pairs of dofs of a :class:`DistributedSpace` (PairJump, distributed).

    Row k: c1_k u[first_k] - c2_k u[second_k]. ``first``/``second`` are local indices (-1: not held).
    """

    def __init__(self, space: DistributedSpace, first: np.ndarray, second: np.ndarray, exchange: NeighbourSum,
                 coef_first: np.ndarray | None = None, coef_second: np.ndarray | None = None) -> None:
        self.space, self.exchange = space, exchange
        n_rows = first.size
        self.coef_first = np.ones(n_rows) if coef_first is None else coef_first
        self.coef_second = np.ones(n_rows) if coef_second is None else coef_second
        self.plain = coef_first is None
        ok1, ok2 = first >= 0, second >= 0
        self.rows1, self.rows2 = np.flatnonzero(ok1), np.flatnonzero(ok2)
        self.first, self.second = first[ok1], second[ok2]
        # contributions to B u from the owner of each dof only (then summed over the ranks of the row)
        own1 = space.owned[self.first]
        own2 = space.owned[self.second]
        self.orow1, self.oidx1 = self.rows1[own1], self.first[own1]
        self.orow2, self.oidx2 = self.rows2[own2], self.second[own2]
        self.n_rows = n_rows

    def matvec(self, u: np.ndarray) -> np.ndarray:
        """B u on this rank's rows (consistent), one neighbour sum."""
        a = np.zeros(self.n_rows)
        b = np.zeros(self.n_rows)
        a[self.orow1] = u[self.oidx1] if self.plain else self.coef_first[self.orow1] * u[self.oidx1]
        b[self.orow2] = u[self.oidx2] if self.plain else self.coef_second[self.orow2] * u[self.oidx2]
        return self.exchange.sum(a - b)

    def rmatvec(self, lam: np.ndarray) -> np.ndarray:
        """B^T lam on this rank's dofs (complete: every holder of a dof holds all its rows)."""
        n = self.space.n
        w1 = lam[self.rows1] if self.plain else self.coef_first[self.rows1] * lam[self.rows1]
        w2 = lam[self.rows2] if self.plain else self.coef_second[self.rows2] * lam[self.rows2]
        return (np.bincount(self.first, weights=w1, minlength=n).astype(np.float64, copy=False)   # float if empty
                - np.bincount(self.second, weights=w2, minlength=n))


@dataclass
class DistributedActiveSet:
    """One active set Z^k on this rank: its multipliers, jumps, G^k and P^k.

    Attributes
    ----------
    active : ndarray of bool, shape (n_gl,)
        The (replicated) diagonal of Z^k.
    rows : ndarray of int, shape (n_local,)
        Positions (in the active list) of the multipliers this rank holds.
    shared : SharedIndex
    jump, scaled_jump_gamma, scaled_jump_global : _LocalPairs
        Z B^_{Gamma,c} and Z B^_{Gamma,c,D} on u_Gamma, Z B_{Gamma_OL,D} on the global interface.
    projection : DistributedProjection or None
        P^k (None without floating bodies).
    n_active : int
        Active multipliers over all ranks.
    """

    active: np.ndarray
    rows: np.ndarray
    shared: SharedIndex
    jump: _LocalPairs
    scaled_jump_gamma: _LocalPairs
    scaled_jump_global: _LocalPairs
    projection: DistributedProjection | None
    n_active: int

    @property
    def n(self) -> int:
        return int(self.rows.size)


class DistributedHybrid:
    """The hybrid method's operators on one rank (see the module docstring).

    Parameters
    ----------
    prob : RankProblem
        Of a multibody or contact problem (``prob.pieces`` from :func:`distribute_hybrid`).
    """

    def __init__(self, prob: RankProblem) -> None:
        t0 = time.perf_counter()
        sub, comm, piece = prob.sub, prob.comm, prob.pieces       # piece: from rank 0 (distribute_hybrid)
        self.prob, self.comm = prob, comm
        gi_mask = piece["gi_mask"]
        gamma_mask = sub.interface | gi_mask
        spaces = piece["spaces"]
        self.gamma = DistributedSpace(sub, gamma_mask, spaces["gamma"], comm)                # u_Gamma
        self.glob = DistributedSpace(sub, gi_mask, spaces["glob"], comm)                     # Gamma_OL
        self.loc = DistributedSpace(sub, sub.interface & ~gi_mask, spaces["loc"], comm)     # Gamma_0
        cache: dict = {}
        self.schur = DirichletSchur(sub, gamma_mask, cache)
        self.floating = piece["floating"]
        self.body_solver = DistributedPrimalSolver(sub, sub.vertex, cache, comm, prob.primal_dofs,
                                                   pinned=piece["pinned"])
        self.local_solver = DistributedPrimalSolver(sub, sub.vertex, cache, comm, piece["local_primal"],
                                                    exclude=gi_mask)
        self.n_factorizations = (self.schur.II.n_new_factorizations + self.body_solver.n_factorizations
                                 + self.local_solver.n_factorizations)
        self.delta_gamma = sub.delta[self.gamma.space.idx]
        self.delta_local = sub.delta[self.loc.space.idx]
        g = self.gamma.space
        body_of_gamma = np.zeros(g.n, dtype=np.int64)
        body_of_gamma[g.pos] = sub.body_of_sub[sub.sub_of_W[g.idx]]
        column = np.full(piece["n_bodies"], -1)
        column[self.floating] = np.arange(self.floating.size)
        self._column_of_body = column
        self.kernel_column = column[body_of_gamma]
        self._floating_sums = FloatingSums(self.kernel_column, self.floating.size, summed=self.gamma.owned)
        self._kernel_count = comm.allreduce_sum(self._floating_sums.counts.astype(float))    # R_c^T R_c
        self.pair_dofs = piece["pair_dofs"]                                # (n_gl, 2)
        self.pair_weight = piece["pair_weight"]                            # (n_gl, 2)
        self.pair_body = piece["pair_body"]                                # (n_gl, 2)
        self.n_gl = int(self.pair_dofs.shape[0])
        self.contact_mask = piece["contact_mask"]
        self.gamma_dofs = piece["gamma_dofs"]
        # (dof, rank) incidences of the global-interface dofs, sorted by dof: who holds the dofs of a multiplier
        self._inc_dof, self._inc_rank = piece["inc_dof"], piece["inc_rank"]
        self.g_hat = self.gamma.exchange.sum(g.gather(self.schur.harmonic_extension_rhs(sub.f_W)))
        self._cache: dict[bytes, DistributedActiveSet] = {}
        self._bddc_op = self._local_op = None       # interface operators of the two solvers
        self.build_operators()
        self.setup_seconds = time.perf_counter() - t0

    # ----------------------------------------------------------- operators
    def S_hat(self, u: np.ndarray) -> np.ndarray:
        """S^_c u on this rank's u_Gamma dofs (consistent)."""
        g = self.gamma
        return g.exchange.sum(self.schur.space_matvec(u, g.space, g.space))

    def build_operators(self) -> None:
        """As :meth:`HybridSolver.build_operators` (no communication: each rank decides from its own
        subdomains, as it would at first use)."""
        _ = self.schur.explicit
        self._bddc_operator()
        self._local_operator()

    def _bddc_operator(self):
        if self._bddc_op is None:            # the serial operator (explicit interface blocks where they pay)
            self._bddc_op = self.body_solver.interface(self.schur.gamma).space_operator(self.gamma.space,
                                                                                        self.delta_gamma)
        return self._bddc_op

    def _local_operator(self):
        if self._local_op is None:
            self._local_op = self.local_solver.interface(self.schur.gamma).space_operator(self.loc.space,
                                                                                          self.delta_local)
        return self._local_op

    def M_bddc(self, r: np.ndarray) -> np.ndarray:
        """R_D^T S~^dagger R_D r (every body; primal copies summed in the coarse problem)."""
        return self.gamma.exchange.sum(self._bddc_operator().apply(r))

    def P_R(self, u: np.ndarray) -> np.ndarray:
        """Remove the mean on every floating body (one Allreduce of k doubles)."""
        if self.floating.size == 0:
            return u
        fs = self._floating_sums
        return fs.subtract(u, self.comm.allreduce_sum(fs.sums(u)) / self._kernel_count)

    def P_R_and_project(self, u: np.ndarray, lam: np.ndarray,
                        P: DistributedProjection) -> tuple[np.ndarray, np.ndarray]:
        """(P_R u, P^k lam) with one Allreduce of 2 k doubles: the two projections of (4.11), which
        act on the two blocks of the same vector, summed together (the values of :meth:`P_R` and
        ``P.apply``; k floating bodies, so P_R and P^k exist together). The shared Allreduce is
        counted in ``P.coarse_seconds`` (the means of the floating bodies are coarse work too)."""
        fs, k = self._floating_sums, self.floating.size
        t0 = time.perf_counter()
        sums = self.comm.allreduce_sum(np.concatenate([fs.sums(u), P.local_sums(lam)]))
        P.coarse_seconds += time.perf_counter() - t0
        return fs.subtract(u, sums[:k] / self._kernel_count), P.apply_summed(lam, sums[k:])

    def kernel_load(self) -> np.ndarray:
        """e = R_c^T g^_c over all ranks, shape (n_float,)."""
        return self.comm.allreduce_sum(self._floating_sums.sums(self.g_hat))

    def _local_solve(self, r: np.ndarray) -> np.ndarray:
        """M_0 r of (4.10) on this rank's Gamma_0 dofs (summed over the ranks sharing them)."""
        return self.loc.exchange.sum(self._local_operator().apply(r))

    def S_ol(self, v: np.ndarray) -> np.ndarray:
        """S~_OL v on this rank's global-interface dofs, as :meth:`HybridSolver.S_ol`."""
        gl, lc = self.glob, self.loc
        x0 = self._local_solve(lc.exchange.sum(self.schur.space_matvec(v, gl.space, lc.space)))
        return gl.exchange.sum(self.schur.space_matvec((v, -x0), (gl.space, lc.space), gl.space))

    def S_ol_energy(self, v: np.ndarray) -> np.ndarray:
        """The energy form E^T S E v of S~_OL on this rank's dofs, as :meth:`HybridSolver.S_ol_energy`."""
        gl, lc = self.glob, self.loc
        spaces = (gl.space, lc.space)
        w = self._local_solve(lc.exchange.sum(self.schur.space_matvec(v, gl.space, lc.space)))
        z_global = gl.exchange.sum(self.schur.space_matvec((v, -w), spaces, gl.space))
        z_local = lc.exchange.sum(self.schur.space_matvec((v, -w), spaces, lc.space))
        y = self._local_solve(z_local)
        return z_global - gl.exchange.sum(self.schur.space_matvec(y, lc.space, gl.space))

    def gathered_u(self, u_g: np.ndarray) -> np.ndarray | None:
        """The global u on rank 0 (None on the others) from this rank's u_Gamma dofs: the interior values by
        discrete harmonic extension, then :func:`~ddsolve.parallel.setup.gather_solution`. Collective."""
        sub = self.prob.sub
        return gather_solution(self.prob, self.schur.interior_solution(sub.f_W, self.gamma.space.scatter(u_g)))

    def M_D(self, a: DistributedActiveSet, lam: np.ndarray, s_ol: str = "thesis") -> np.ndarray:
        """Z B_{Gamma_OL,D} S~_OL B_{Gamma_OL,D}^T Z lam (``s_ol``: "thesis" or "energy")."""
        if s_ol not in S_OL_FORMS:
            raise InputError("s_ol", f"unknown form {s_ol!r} (choose from {', '.join(S_OL_FORMS)})")
        S = self.S_ol if s_ol == "thesis" else self.S_ol_energy
        return a.scaled_jump_global.matvec(S(a.scaled_jump_global.rmatvec(lam)))

    # ------------------------------------------------------------ active set
    def active_set(self, active: np.ndarray) -> DistributedActiveSet:
        """This rank's part of Z^k (cached by the mask bytes)."""
        active = np.asarray(active, dtype=bool)
        if active.shape != (self.n_gl,):
            raise ValueError(f"active must have shape ({self.n_gl},), got {active.shape}")
        key = np.packbits(active).tobytes()
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        comm = self.comm
        dofs = self.pair_dofs[active]
        n_act = dofs.shape[0]
        # every (row, rank) incidence: the ranks holding the first or the second dof of the row
        inc_rows, inc_ranks = [], []
        for side in (0, 1):
            lo = np.searchsorted(self._inc_dof, dofs[:, side], "left")
            hi = np.searchsorted(self._inc_dof, dofs[:, side], "right")
            cnt = hi - lo
            idx = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(lo, cnt)
            inc_rows.append(np.repeat(np.arange(n_act), cnt))
            inc_ranks.append(self._inc_rank[idx])
        inc_rows, inc_ranks = np.concatenate(inc_rows), np.concatenate(inc_ranks)
        rows = np.unique(inc_rows[inc_ranks == comm.rank])
        shared = SharedIndex.build(comm.rank, rows, inc_rows, inc_ranks, n_act)
        exchange = NeighbourSum(comm, shared)
        d = dofs[rows]
        w = self.pair_weight[active][rows]
        ga, gb = self.gamma.local_index(d[:, 0]), self.gamma.local_index(d[:, 1])
        jump = _LocalPairs(self.gamma, ga, gb, exchange)
        scaled_gamma = _LocalPairs(self.gamma, ga, gb, exchange, w[:, 1], w[:, 0])
        # B_D: the entry of copy a is multiplied by the weight of b and vice versa
        scaled = _LocalPairs(self.glob, self.glob.local_index(d[:, 0]), self.glob.local_index(d[:, 1]), exchange,
                             w[:, 1], w[:, 0])
        projection = None
        k = self.floating.size
        if k:
            bodies = self.pair_body[active][rows]
            c1, c2 = self._column_of_body[bodies[:, 0]], self._column_of_body[bodies[:, 1]]
            r = np.arange(rows.size)
            G = sp.csr_matrix((np.r_[np.ones(int((c1 >= 0).sum())), -np.ones(int((c2 >= 0).sum()))],
                               (np.r_[r[c1 >= 0], r[c2 >= 0]], np.r_[c1[c1 >= 0], c2[c2 >= 0]])),
                              shape=(rows.size, k))
            projection = DistributedProjection(G, shared.owned, comm)
        a = DistributedActiveSet(active=active.copy(), rows=rows, shared=shared, jump=jump,
                                 scaled_jump_gamma=scaled_gamma, scaled_jump_global=scaled,
                                 projection=projection, n_active=int(n_act))
        if len(self._cache) > 16:
            self._cache.clear()
        self._cache[key] = a
        return a

    # ---------------------------------------------------------------- solve
    def solve(self, active: np.ndarray, *, rtol: float = 1e-6, maxiter: int = 1000, restart: int = 100,
              norm: str = "l2", rtol_rule: str = "max", gather: bool = True,
              x0: dict | None = None, multiplier_weight: float = 1.0,
              s_ol: str = "thesis") -> tuple[MethodOutput, dict]:
        """PCR on (4.5) with (4.11) for Z^k = ``active``, as :meth:`HybridSolver.solve` (orthogonal P^k).

        ``multiplier_weight`` c: PCR runs on D A D with D = diag(I, c I), as in the serial solver
        (the face-solve stopping rule of the active set's ``face_norm="scaled"``).

        ``x0``: warm start ``{"u_gamma": (n,) this rank's u_Gamma, "lambda": (n_gl,) replicated
        multipliers of all pairs}`` (as the serial ``extra["state"]``; kept on active pairs).

        Returns ``(output, info)`` as :func:`ddsolve.parallel.fetidp.solve_fetidp_mpi`; ``output.u``
        is the global solution on rank 0 when ``gather``; ``output.extra`` also holds this rank's
        ``lambda`` (its active rows) and ``u_gamma``.
        """
        t0 = time.perf_counter()
        a = self.active_set(active)
        n_g, n_act = self.gamma.n, a.n
        nf = self.floating.size
        P = a.projection
        lam0 = P.particular(self.kernel_load()) if P is not None else np.zeros(n_act)

        def proj(v: np.ndarray) -> np.ndarray:
            return v if P is None else P.apply(v)

        def A_op(x: np.ndarray) -> np.ndarray:                  # (4.13)
            u, mu = x[:n_g], x[n_g:]
            jump = a.jump.matvec(u)
            mu, jump = (mu, jump) if P is None else P.apply_pair(mu, jump)    # one Allreduce for both
            return np.concatenate([self.S_hat(u) + a.jump.rmatvec(mu), jump])

        def M_op(r: np.ndarray) -> np.ndarray:                  # (4.11)
            if P is None:                   # no floating body: P_R = I, P^k = I
                return np.concatenate([self.M_bddc(r[:n_g]), self.M_D(a, r[n_g:], s_ol)])
            ru, rl = self.P_R_and_project(r[:n_g], r[n_g:], P)      # P_R and P^k: one Allreduce each side
            return np.concatenate(self.P_R_and_project(self.M_bddc(ru), self.M_D(a, rl, s_ol), P))

        b = np.concatenate([self.g_hat - a.jump.rmatvec(lam0), np.zeros(n_act)])
        owned = np.concatenate([self.gamma.owned, a.shared.owned])
        n = n_g + n_act
        A, M = linear_operator(n, A_op), linear_operator(n, M_op)
        xs = None
        if x0 is not None:                   # HybridSolver._initial_guess: range(P_R) x V^k
            lam = np.asarray(x0["lambda"], dtype=float)[a.active][a.rows]
            xs = np.concatenate([self.P_R(np.asarray(x0["u_gamma"], dtype=float)), proj(lam - lam0)])
        c = float(multiplier_weight)
        if not (c > 0.0 and math.isfinite(c)):
            raise InputError("multiplier_weight", f"must be positive and finite, got {multiplier_weight!r}")
        if c != 1.0:                         # D A D y = D b, x = D y (HybridSolver.solve)
            d = np.r_[np.ones(n_g), np.full(n_act, c)]
            A_c, M_c = A, M
            A = linear_operator(n, lambda x: d * (A_c @ (d * x)))
            M = linear_operator(n, lambda r: (M_c @ (r / d)) / d)
            b = d * b
            xs = None if xs is None else xs / d
        setup = time.perf_counter() - t0
        mpi_at_setup = self.comm.counters.seconds     # the solve's MPI time starts here
        t1 = time.perf_counter()
        reductions = Reductions(self.comm, owned)
        atol = rtol * _rhs_norm(b, M.matvec, norm, reductions) if rtol_rule == "max" else 0.0
        if not math.isfinite(atol):      # as serial: b beyond the double range is PCR's breakdown (a global
            atol = 0.0                   # norm: the same on every rank), not an input error
        counter = IterationCounter(self.comm)
        if self.gamma.n_global + a.n_active == 0:      # one part per body, no multipliers (as serial): nothing
            kr = KrylovResult.solved_directly(n, "interface unknowns")      # to iterate on, on any rank
        else:
            kr = DistributedPCR.restarted(A, b, xs, rtol=rtol, atol=atol, maxiter=maxiter, restart=restart, M=M,
                                          norm=norm, comm=self.comm, owned=owned, callback=counter)
        krylov_seconds = time.perf_counter() - t1
        u_g = kr.x[:n_g]
        lam = lam0 + proj(kr.x[n_g:] * c if c != 1.0 else kr.x[n_g:])
        if P is not None:                    # u_Gamma - R_c (G^T G)^{-1} G^T Z B^ u_Gamma
            beta = P.coefficients(a.jump.matvec(u_g))
            u_g = u_g - np.where(self.kernel_column >= 0, beta[np.maximum(self.kernel_column, 0)], 0.0)
        u = self.gathered_u(u_g) if gather else None      # the interior completion only for a gathered u
        jump = self.comm.allreduce_scalar(float(np.abs(a.jump.matvec(u_g)).max()) if n_act else 0.0, op="max")
        coarse = self.body_solver.coarse_seconds + self.local_solver.coarse_seconds + (
            P.coarse_seconds if P is not None else 0.0)
        out = MethodOutput(u=u, krylov=kr, nlambda=a.n_active, n_factorizations=self.n_factorizations,
                           setup_seconds=self.setup_seconds + setup,
                           extra={"n_gamma": self.gamma.n_global, "n_floating": int(nf), "n_active": a.n_active,
                                  "constraint_residual": jump, "lambda": lam, "u_gamma": u_g, "s_ol": s_ol})
        info = {"mpi_at_setup": mpi_at_setup, "coarse_seconds": coarse, "krylov_seconds": krylov_seconds,
                "per_iteration": counter.per_iteration(kr.iterations)}
        return out, info


def _rhs_norm(b: np.ndarray, M, norm: str, red: Reductions) -> float:
    """:meth:`ddsolve.krylov.pcr.PCR.rhs_norm` over ranks: ||b||_2, or |<b, M b>|^{1/2} for ``norm="M"``."""
    if norm != "M":
        return red.l2norm(b)
    amax = red.absmax(b)
    scale = 1.0
    if 0.0 < amax < math.inf and not -64 <= math.frexp(amax)[1] <= 64:
        scale = math.ldexp(1.0, max(-1000, min(1000, -math.frexp(amax)[1])))
    bs = b * scale if scale != 1.0 else b
    return math.sqrt(abs(red.inner(bs, M(bs)))) / scale


def solve_hybrid_mpi(prob: RankProblem, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
                     gather: bool = True, norm: str = "l2", projection: str = "orthogonal",
                     restart: int = 100, rtol_rule: str = "max", s_ol_fallback: bool = True) -> tuple[MethodOutput, dict]:
    """The hybrid method on the ranks of ``prob.comm`` for the active set of ``prob.spec.contact``.

    ``cond`` is ignored (PCR has no Lanczos estimate, as in serial; logged). Only ``projection="orthogonal"``.
    ``s_ol_fallback``: as serial (:func:`~ddsolve.multibody.fallback.with_s_ol_fallback`; every rank sees the
    same breakdown, the reductions being replicated).
    """
    if projection != "orthogonal":
        raise ValueError(f"projection {projection!r} is not distributed (only 'orthogonal')")
    if cond:
        log.warning(NO_COND_MESSAGE)
    hyb = DistributedHybrid(prob)
    out, info = with_s_ol_fallback(lambda s_ol: hyb.solve(hyb.contact_mask, rtol=rtol, maxiter=maxiter,
                                                          restart=restart, norm=norm, rtol_rule=rtol_rule,
                                                          gather=gather, s_ol=s_ol), s_ol_fallback)
    tied = prob.pieces["tied"]
    if out.krylov.converged and tied is not None:      # as serial: the error of u itself
        sub = prob.sub
        u_W = hyb.schur.interior_solution(sub.f_W, hyb.gamma.space.scatter(out.extra["u_gamma"]))
        out.extra["error_estimate"], n_check = distributed_multibody_estimate(
            sub, u_W, prob.comm, tied, prob.pieces["gi_mask"])
        out.n_factorizations += n_check
    return out, info
