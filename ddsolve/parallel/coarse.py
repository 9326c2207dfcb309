"""The primal-constrained solve A~^{-1} of (2.17) over ranks, coarse problem redundant.

Coarse problem. Every rank computes the local coarse matrices
A_PiPi^(i) - A_Pir^(i) Psi^(i) of its subdomains (as in serial), the
contributions are allgathered once at setup (COO triplets, in rank order) and
every rank assembles and factors the whole S_PiPi (one sparse LU). Per
application of A~^{-1} the primal right-hand side is summed with one
Allreduce of n_primal doubles and solved redundantly on every rank. Why
redundant: the coarse space is small (one dof per cross point), its solve
costs less than a gather to one rank plus a scatter back (two latency-bound
messages per application on the critical path), and every rank needs the
u_Pi of its subdomains anyway. The limit of this choice (the allgather and
the redundant factorization grow with P) is what the performance model of
:mod:`ddsolve.parallel.model` projects.

Where the coarse matrix falls apart into independent blocks (its connected
components: one per body in multibody and contact scenes, whose primal
vertices couple only within their body), a rank factors and solves only the
blocks holding a coarse dof of its own subdomains (:class:`RestrictedCoarse`).
Two contact membranes on two ranks: each rank solves its body's block, half
the coarse problem. With one block (a single body) nothing changes.

The right-hand side of a block that no other rank touches is complete on its
rank, so the Allreduce runs only over the ranks that share a block with
another rank (a sub-communicator, :meth:`CountingComm.split`, made once at
setup), and not at all where every block is one rank's own: bodies dealt
out whole to the ranks, the usual case of the hybrid method and FETI-FETI.
The solution is the same: the sum over the other ranks adds only zeros there.
"""
from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..dd.operators import PrimalConstrainedSolver
from ..dd.coarse import coarse_factor
from ..dd.primal import first_entry_of_bodies
from .comm import CountingComm

__all__ = ["DistributedPrimalSolver", "RestrictedCoarse", "pinned_vertices"]


class DistributedPrimalSolver(PrimalConstrainedSolver):
    """:class:`PrimalConstrainedSolver` on a :class:`~ddsolve.parallel.distribute.RankSubstructures`.

    Parameters
    ----------
    sub : RankSubstructures
    primal_mask : ndarray of bool, shape (sub.n_W,)
    cache : dict
    comm : CountingComm
    primal_dofs : ndarray of int
        Sorted global dofs of all primal unknowns (from the topology).
    pinned : sequence of int, optional
        Coarse dofs pinned to zero (one primal vertex per floating body, chosen from the global
        topology as the serial ``fixed_bodies`` does, :func:`pinned_vertices`): A~^+ of FETI-FETI and
        of the hybrid method.
    exclude : ndarray of bool, shape (sub.n_W,), optional
        As for :class:`PrimalConstrainedSolver` (``primal_dofs`` then lists the primal dofs outside it).

    Attributes
    ----------
    coarse_seconds : float
        Time in the coarse problem on this rank: the setup reduction and every
        coarse right-hand side reduction and solve.
    coarse_comm : CountingComm or None
        The ranks over which the coarse right-hand side is summed (None: this rank's coarse
        blocks are its own, no reduction).
    """

    def __init__(self, sub, primal_mask: np.ndarray, cache: dict, comm: CountingComm,
                 primal_dofs: np.ndarray, pinned: Sequence[int] = (), exclude: np.ndarray | None = None) -> None:
        self.comm = comm
        self._all_primal = np.asarray(primal_dofs, dtype=np.int64)
        self._pinned = np.asarray(pinned, dtype=np.int64)
        self.coarse_seconds = 0.0
        self.coarse_comm: CountingComm | None = comm       # narrowed by _factor_coarse
        t0 = time.perf_counter()
        # no fixed_bodies: a rank may not hold the pinned entry (see pinned_vertices)
        super().__init__(sub, primal_mask, cache, exclude=exclude)
        self.pinned = self._pinned
        if self.coarse is not None:
            self.coarse = _SummedCoarse(self.coarse, self)
        self.coarse_setup_seconds = time.perf_counter() - t0

    def _primal_dofs(self, sub, primal_mask: np.ndarray) -> np.ndarray:
        return self._all_primal

    def _assemble_coarse(self, S_PiPi: sp.csr_matrix) -> sp.csr_matrix:
        t0 = time.perf_counter()
        coo = S_PiPi.tocoo()
        parts = self.comm.allgather((coo.row.astype(np.int64), coo.col.astype(np.int64), coo.data))
        rows = np.concatenate([p[0] for p in parts])
        cols = np.concatenate([p[1] for p in parts])
        vals = np.concatenate([p[2] for p in parts])
        S = sp.csr_matrix((vals, (rows, cols)), shape=S_PiPi.shape)
        if self._pinned.size:                           # as PrimalConstrainedSolver with fixed_bodies
            keep = np.ones(S.shape[0])
            keep[self._pinned] = 0.0
            D = sp.diags(keep)
            S = D @ S @ D + sp.diags(1.0 - keep)
        self.coarse_seconds += time.perf_counter() - t0
        return S

    def _factor_coarse(self, S_PiPi: sp.csc_matrix):
        """The factor of the blocks of S_PiPi that hold a coarse dof of this rank, and the communicator
        of the coarse right-hand side's sum (``self.coarse_comm``; see the module docstring). Collective."""
        touched = np.zeros(self.n_primal, dtype=bool)
        touched[self.coarse_of_W[self.primal]] = True
        components = connected_components(S_PiPi, directed=False)
        self.coarse_comm = self._reduction_comm(components, touched)
        return RestrictedCoarse.of(S_PiPi, touched, components)

    def _reduction_comm(self, components: tuple[int, np.ndarray], touched: np.ndarray) -> CountingComm | None:
        """The ranks that share a coarse block with another rank (one allgather of block numbers and,
        unless all or none of the ranks do, one ``Split``): their communicator, or None on a rank whose
        blocks are all its own."""
        n_comp, label = components
        mine = np.unique(label[touched])
        per_rank = self.comm.allgather(mine)
        ranks_of_block = np.bincount(np.concatenate(per_rank), minlength=n_comp)
        shares = [bool((ranks_of_block[blocks] > 1).any()) for blocks in per_rank]
        if all(shares):
            return self.comm
        if not any(shares):
            return None
        return self.comm.split(tuple(shares))


class RestrictedCoarse:
    """The factor of the diagonal blocks of a block-diagonal coarse matrix that a rank reads.

    Parameters
    ----------
    factor : object with ``solve``
        Factor of ``S[np.ix_(index, index)]``.
    index : ndarray of int, shape (m,)
        Sorted coarse dofs of the kept blocks.
    n : int
        Size of the coarse problem.

    ``solve(b)`` returns a vector of length n: the solution on ``index`` (each kept block is
    independent of the others, so these entries are those of the whole solve) and zero elsewhere,
    entries the rank never reads.
    """

    def __init__(self, factor, index: np.ndarray, n: int) -> None:
        self.factor, self.index, self.n = factor, index, n

    @classmethod
    def of(cls, S: sp.spmatrix, touched: np.ndarray, components: tuple[int, np.ndarray] | None = None):
        """The factor of the connected components of S (an undirected graph) that meet ``touched``:
        :func:`~ddsolve.dd.coarse.coarse_factor` of S itself when that is all of them.

        Parameters
        ----------
        S : sparse matrix, shape (n, n)
            Structurally symmetric.
        touched : ndarray of bool, shape (n,)
        components : (int, ndarray of int), optional
            ``scipy.sparse.csgraph.connected_components(S, directed=False)``, if already computed.
        """
        n_comp, label = connected_components(S, directed=False) if components is None else components
        need = np.zeros(n_comp, dtype=bool)
        need[label[touched]] = True
        keep = need[label]
        if keep.all():
            return coarse_factor(S)
        index = np.flatnonzero(keep)
        S = sp.csr_matrix(S)
        return cls(coarse_factor(S[index][:, index]), index, S.shape[0])

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = np.zeros(self.n)
        x[self.index] = self.factor.solve(b[self.index])
        return x


class _SummedCoarse:
    """The coarse factor of a :class:`DistributedPrimalSolver`: sums the coarse right-hand side over
    the ranks of ``owner.coarse_comm`` (one Allreduce of n_primal doubles; none where that is None)
    before the redundant solve.

    Every path of :class:`PrimalConstrainedSolver` (the W-level ``solve`` and the explicit
    interface blocks of ``interface(...)``) calls ``coarse.solve`` once per application, on its
    partial coarse right-hand side, so all of them run distributed unchanged.
    """

    def __init__(self, factor, owner: "DistributedPrimalSolver") -> None:
        self.factor = factor
        self.owner = owner

    def solve(self, b_pi: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        comm = self.owner.coarse_comm
        b_pi = comm.allreduce_sum(b_pi) if comm is not None else np.array(b_pi, dtype=np.float64)
        b_pi[self.owner.pinned] = 0.0
        u_pi = self.factor.solve(b_pi)
        self.owner.coarse_seconds += time.perf_counter() - t0
        return u_pi


def pinned_vertices(topo, floating_bodies, primal_dofs: np.ndarray) -> list[int]:
    """Coarse index of the pinned vertex of every floating body: its first primal W entry (the serial choice).

    Parameters
    ----------
    topo : Substructures
        Global topology.
    floating_bodies : sequence of int
    primal_dofs : ndarray of int
        Sorted global dofs of the primal unknowns.

    Raises
    ------
    ValueError
        A floating body without a primal vertex.
    """
    first = first_entry_of_bodies(topo.vertex, topo.body_of_sub[topo.sub_of_W], floating_bodies)
    return [int(c) for c in np.searchsorted(primal_dofs, topo.l2g[first])]
