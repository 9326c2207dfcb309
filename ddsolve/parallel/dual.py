"""Projected PCG on a distributed dual problem: :func:`ddsolve.dd.dual.solve_dual` over ranks.

Shared by the distributed one-level FETI (:mod:`ddsolve.parallel.feti`) and
FETI-FETI (:mod:`ddsolve.parallel.fetifeti`). The multipliers are rank-local
vectors with consistent copies of shared entries (:class:`~ddsolve.parallel.comm.SharedIndex`);
F and M end with a neighbour sum. The natural coarse space G = B R is known
row by row where the row lives; the projection (2.13) in the scaled unknowns
mu = Q^{-1/2} lambda,

    P v = v - G_s (G_s^T G_s)^{-1} G_s^T v,   G_s = Q^{1/2} G,

needs G_s^T v, a sum over all multipliers: the owned rows of every rank and
one Allreduce of k doubles (k: floating subdomains or bodies). G_s^T G_s
(k x k) is summed once over ranks (allgather of the COO triplets of the
owned rows' products) and factored redundantly on every rank
(:class:`DistributedProjection`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..dd.dual import q_scaled
from ..dd.operators import linear_operator
from ..krylov.result import KrylovResult
from .comm import CountingComm
from .krylov import distributed_pcg

__all__ = ["DistributedProjection", "DistributedDualSolution", "distributed_solve_dual"]

Matvec = Callable[[np.ndarray], np.ndarray]


class DistributedProjection:
    """P = I - G (G^T G)^{-1} G^T for G given by the local rows of every rank (see the module docstring).

    Parameters
    ----------
    G : scipy.sparse matrix, shape (n_local, k)
        Full rows of this rank's multipliers (k global columns).
    owned : ndarray of bool, shape (n_local,)
    comm : CountingComm

    Attributes
    ----------
    coarse_seconds : float
        Time in the coarse problem on this rank (setup reduction and factorization, every
        reduction of G^T v and coarse solve, waits at the reductions included; each counted once,
        and a reduction that sums G^T v with other values, :meth:`apply_pair` or
        :meth:`~ddsolve.parallel.hybrid.DistributedHybrid.P_R_and_project`, counted whole).
    """

    def __init__(self, G: sp.spmatrix, owned: np.ndarray, comm: CountingComm) -> None:
        self.G = G.tocsr()
        self.GT_owned = sp.csr_matrix(G[owned]).T.tocsr()
        self.owned = owned
        self.comm = comm
        self.coarse_seconds = 0.0
        t0 = time.perf_counter()
        Go = sp.csr_matrix(G[owned])
        GtG = (Go.T @ Go).tocoo()
        parts = comm.allgather((GtG.row.astype(np.int64), GtG.col.astype(np.int64), GtG.data))
        k = G.shape[1]
        GtG = sp.csc_matrix((np.concatenate([p[2] for p in parts]),
                             (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))),
                            shape=(k, k))
        self.factor = spla.splu(GtG)
        self.coarse_seconds += time.perf_counter() - t0

    def coarse_solve(self, x: np.ndarray) -> np.ndarray:
        return self.factor.solve(x)

    def reduce(self, v: np.ndarray) -> np.ndarray:
        """G^T v over all ranks (owned rows only, one Allreduce)."""
        t0 = time.perf_counter()
        out = self.comm.allreduce_sum(self.local_sums(v))
        self.coarse_seconds += time.perf_counter() - t0
        return out

    def apply(self, v: np.ndarray) -> np.ndarray:
        return self.apply_summed(v, self.reduce(v))      # each counts its own part of coarse_seconds once

    def apply_pair(self, v: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P v, P w) with one Allreduce of 2 k doubles (the values of :meth:`apply`)."""
        k = self.G.shape[1]
        t0 = time.perf_counter()
        gt = self.comm.allreduce_sum(np.concatenate([self.local_sums(v), self.local_sums(w)]))
        self.coarse_seconds += time.perf_counter() - t0
        return self.apply_summed(v, gt[:k]), self.apply_summed(w, gt[k:])

    def local_sums(self, v: np.ndarray) -> np.ndarray:
        """This rank's share of G^T v (its owned rows), shape (k,): :meth:`reduce` before its Allreduce."""
        return self.GT_owned @ v[self.owned]

    def apply_summed(self, v: np.ndarray, gtv: np.ndarray) -> np.ndarray:
        """P v from G^T v already summed over ranks (``gtv``, shape (k,)): :meth:`apply` after its
        reduction, for a caller that sums G^T v together with other values."""
        t0 = time.perf_counter()
        y = self.coarse_solve(gtv)
        self.coarse_seconds += time.perf_counter() - t0
        return v - self.G @ y

    def particular(self, e: np.ndarray) -> np.ndarray:
        return self.G @ self.coarse_solve(e)

    def coefficients(self, r: np.ndarray) -> np.ndarray:
        gtv = self.reduce(r)
        t0 = time.perf_counter()
        y = self.coarse_solve(gtv)
        self.coarse_seconds += time.perf_counter() - t0
        return y


@dataclass
class DistributedDualSolution:
    """This rank's lambda, the kernel coefficients alpha (None without kernel), the PCG result.

    ``per_iteration``: (messages, bytes, allreduces) of this rank per iteration;
    ``krylov_seconds``: the PCG loop; ``coarse_seconds``: the projection's time.
    """

    lam: np.ndarray
    alpha: np.ndarray | None
    krylov: KrylovResult
    per_iteration: tuple
    krylov_seconds: float
    coarse_seconds: float


def distributed_solve_dual(F: Matvec, M: Matvec, d: np.ndarray, G: sp.spmatrix | None, e: np.ndarray | None,
                           q: np.ndarray | None, *, comm: CountingComm, owned: np.ndarray, rtol: float = 1e-6,
                           maxiter: int = 1000, cond: bool = False,
                           n_global: int | None = None) -> DistributedDualSolution:
    """:func:`ddsolve.dd.dual.solve_dual` on rank-local multipliers.

    ``n_global``: the number of multipliers over all ranks; 0 returns at once, solved directly (as serial).

    Parameters
    ----------
    F, M : callable
        Consistent (neighbour-summed) operators on this rank's multipliers, shape (n,) -> (n,).
    d : ndarray, shape (n,)
    G : sparse matrix, shape (n, k), or None
        This rank's rows of the natural coarse space B R (k global columns).
    e : ndarray, shape (k,)
        R^T f summed over all ranks.
    q : ndarray, shape (n,), optional
        Diagonal of Q on this rank's multipliers (None: Q = I).
    comm : CountingComm
    owned : ndarray of bool, shape (n,)
        Entries counted in inner products.
    """
    n = d.shape[0]
    if n_global == 0:       # no multipliers on any rank (a tiny mesh): nothing to iterate
        kr = KrylovResult.solved_directly(n)
        k = 0 if G is None else G.shape[1]
        return DistributedDualSolution(lam=np.zeros(n), alpha=np.zeros(k) if k else None, krylov=kr,
                                       per_iteration=(0.0, 0.0, 0.0), krylov_seconds=0.0, coarse_seconds=0.0)
    sq, F_scaled, M_scaled, d_scaled = q_scaled(F, M, d, q)
    mu0 = np.zeros(n)
    proj = None
    if G is not None and G.shape[1] > 0:
        proj = DistributedProjection((sp.diags(sq) @ G).tocsr(), owned, comm)
        mu0 = proj.apply(mu0) + proj.particular(e)
    t1 = time.perf_counter()
    kr, per_iteration = distributed_pcg(
        linear_operator(n, F_scaled), d_scaled, mu0, comm=comm, owned=owned, rtol=rtol, maxiter=maxiter,
        M=linear_operator(n, M_scaled), P=None if proj is None else linear_operator(n, proj.apply), cond=cond)
    krylov_seconds = time.perf_counter() - t1
    alpha = proj.coefficients(F_scaled(kr.x) - d_scaled) if proj is not None else None
    return DistributedDualSolution(lam=sq * kr.x, alpha=alpha, krylov=kr, per_iteration=per_iteration,
                                   krylov_seconds=krylov_seconds,
                                   coarse_seconds=0.0 if proj is None else proj.coarse_seconds)
