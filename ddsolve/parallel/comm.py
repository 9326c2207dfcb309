"""A counting wrapper of an mpi4py communicator and the neighbour exchange of shared values.

:class:`CountingComm` forwards the few MPI calls the distributed solvers use
and counts point-to-point messages, their bytes and the global reductions, so
that the JSON of a parallel solve can report them per iteration (the input of
the alpha-beta model of :mod:`ddsolve.parallel.model`).

:class:`NeighbourSum` is the one communication pattern of the distributed
operators: every rank holds, for each *shared index* (a Lagrange multiplier
of FETI-DP, an interface dof of BDDC), its own partial value; after
:meth:`NeighbourSum.sum` every rank holding the index has the total, summed
in increasing rank order, so that all copies are bitwise identical.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["CommCounters", "CountingComm", "NeighbourSum", "SharedIndex", "shared_indices"]


#: The MPI attribute key of :func:`_split_cache` (made on first use).
_SPLITS_KEYVAL: Any = None


def _split_cache(comm: Any) -> dict:
    """The sub-communicators :meth:`CountingComm.split` made from ``comm``, by member tuple: a dict held as an
    MPI attribute of ``comm`` (deleted with it by ``Free``), local to this rank."""
    global _SPLITS_KEYVAL
    from mpi4py import MPI

    if _SPLITS_KEYVAL is None:
        _SPLITS_KEYVAL = MPI.Comm.Create_keyval()
    cache = comm.Get_attr(_SPLITS_KEYVAL)
    if cache is None:
        cache = {}
        comm.Set_attr(_SPLITS_KEYVAL, cache)
    return cache


@dataclass
class CommCounters:
    """Messages and bytes sent by this rank, and reductions it took part in."""

    messages: int = 0
    bytes: int = 0
    allreduces: int = 0
    seconds: float = 0.0          # wall time inside MPI calls (transfer and waiting for other ranks)

    def snapshot(self) -> tuple[int, int, int]:
        return self.messages, self.bytes, self.allreduces


class CountingComm:
    """An mpi4py communicator with message, byte and reduction counters.

    Parameters
    ----------
    comm : mpi4py.MPI.Comm
    """

    def __init__(self, comm: Any) -> None:
        from mpi4py import MPI

        self.MPI = MPI
        self.comm = comm
        self.rank = comm.Get_rank()
        self.size = comm.Get_size()
        self.counters = CommCounters()

    def split(self, members: tuple[bool, ...]) -> "CountingComm | None":
        """The sub-communicator of the ranks r with ``members[r]`` (the same tuple on every rank), counting
        into the same counters; None on the other ranks.

        Collective over this communicator the first time a tuple is seen: the MPI communicator is made
        once per communicator and tuple, so that repeated solves do not use up MPI's communicator ids.
        The cache is an MPI attribute of the communicator (:func:`_split_cache`), so it goes with it: a
        cache keyed by the handle returned another communicator's entry once MPI reused a freed
        handle (a review: wrong sums and a hang).
        """
        key = tuple(bool(m) for m in members)
        cache = _split_cache(self.comm)
        sub = cache.get(key)
        if sub is None:
            sub = self.comm.Split(0 if key[self.rank] else self.MPI.UNDEFINED, self.rank)
            cache[key] = sub
        if not key[self.rank]:
            return None
        out = CountingComm(sub)
        out.counters = self.counters
        return out

    # ------------------------------------------------------------ reductions
    def allreduce_sum(self, x: np.ndarray) -> np.ndarray:
        """Elementwise sum over ranks of a float64 array (one Allreduce)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        out = np.empty_like(x)
        t0 = time.perf_counter()
        self.comm.Allreduce(x, out, op=self.MPI.SUM)
        self.counters.seconds += time.perf_counter() - t0
        self.counters.allreduces += 1
        return out

    def allreduce_scalar(self, value: float, op: str = "sum") -> float:
        """Sum (or max) of one float over ranks."""
        x = np.array([value], dtype=np.float64)
        out = np.empty(1)
        t0 = time.perf_counter()
        self.comm.Allreduce(x, out, op=self.MPI.SUM if op == "sum" else self.MPI.MAX)
        self.counters.seconds += time.perf_counter() - t0
        self.counters.allreduces += 1
        return float(out[0])

    def allgather(self, obj: Any) -> list:
        """Python-object allgather (setup only; counted as one reduction)."""
        self.counters.allreduces += 1
        return self.comm.allgather(obj)

    def gather(self, obj: Any, root: int = 0) -> list | None:
        return self.comm.gather(obj, root=root)

    def barrier(self) -> None:
        self.comm.Barrier()

    # ---------------------------------------------------------- point to point
    def exchange(self, sends: dict[int, np.ndarray], recv_sizes: dict[int, int], tag: int = 7) -> dict[int, np.ndarray]:
        """Send ``sends[q]`` to every neighbour q and receive ``recv_sizes[q]`` doubles from it (Isend/Irecv)."""
        t0 = time.perf_counter()
        requests, received = [], {}
        for q, n in recv_sizes.items():
            buf = np.empty(n)
            received[q] = buf
            requests.append(self.comm.Irecv(buf, source=q, tag=tag))
        for q, data in sends.items():
            data = np.ascontiguousarray(data, dtype=np.float64)
            requests.append(self.comm.Isend(data, dest=q, tag=tag))
            self.counters.messages += 1
            self.counters.bytes += data.nbytes
            sends[q] = data                         # keep the buffer alive until Waitall
        self.MPI.Request.Waitall(requests)
        self.counters.seconds += time.perf_counter() - t0
        return received

    def abort(self, code: int = 1) -> None:
        self.comm.Abort(code)


@dataclass
class SharedIndex:
    """Local indices of a distributed index set and how they are shared.

    Attributes
    ----------
    n : int
        Local length (every index touched by this rank's subdomains).
    owned : ndarray of bool, shape (n,)
        True where this rank is the lowest rank holding the index (counted in inner products).
    neighbours : dict
        Neighbour rank -> local positions of the indices shared with it, in increasing global order
        (the same order on both sides).
    n_global : int
        Length of the global index set.
    """

    n: int
    owned: np.ndarray
    neighbours: dict[int, np.ndarray] = field(default_factory=dict)
    n_global: int = 0

    @classmethod
    def build(cls, rank: int, local_gid: np.ndarray, pair_gid: np.ndarray, pair_rank: np.ndarray,
              n_global: int) -> "SharedIndex":
        """From the (global index, rank) incidences of all ranks.

        Parameters
        ----------
        rank : int
        local_gid : ndarray of int, shape (n,)
            Sorted global ids of this rank's indices (every id with an incidence of ``rank``).
        pair_gid, pair_rank : ndarray of int
            Every (global id, rank touching it) incidence (duplicates allowed), or those of the ids of
            ``local_gid`` only.
        n_global : int
        """
        size = max(int(pair_rank.max(initial=0)), rank) + 1
        gids, index = shared_indices(pair_gid, pair_rank, size, n_global, ranks=(rank,))[0]
        if not np.array_equal(gids, local_gid):
            raise ValueError("local_gid must be the sorted ids of this rank's incidences")
        return index


def shared_indices(gid: np.ndarray, rank: np.ndarray, size: int, n_global: int,
                   ranks=None) -> list[tuple[np.ndarray, SharedIndex]]:
    """The :class:`SharedIndex` of every rank from the (global id, rank) incidences, at once.

    O(m log m) in the number m of incidences, whatever the number of ranks: one sort of the
    (id, rank) keys; the neighbours come from the ids held by two or more ranks only.

    Parameters
    ----------
    gid, rank : ndarray of int, shape (m,)
        Every (global id, rank holding it) incidence; duplicates allowed.
    size : int
        Number of ranks.
    n_global : int
        Length of the global index set.
    ranks : sequence of int, optional
        Only these ranks (default: all).

    Returns
    -------
    list of (local_gid, SharedIndex)
        Per rank of ``ranks``: the sorted global ids it holds and their sharing.
    """
    key = np.unique(np.asarray(gid, dtype=np.int64) * size + np.asarray(rank, dtype=np.int64))
    g, r = np.divmod(key, size)                              # sorted by id, then rank
    first = np.r_[True, g[1:] != g[:-1]] if g.size else np.zeros(0, dtype=bool)
    starts = np.flatnonzero(first)
    counts = np.diff(np.r_[starts, g.size])
    lowest = np.repeat(r[starts], counts)                    # lowest rank holding the id of each key
    # ordered pairs (id, q, p) of distinct ranks q != p holding the same id
    pair_g, pair_q, pair_p = [], [], []
    for shift in range(1, int(counts.max(initial=1))):
        same = np.flatnonzero(g[shift:] == g[:-shift])
        pair_g += [g[same], g[same]]
        pair_q += [r[same], r[same + shift]]
        pair_p += [r[same + shift], r[same]]
    pg, pq, pp = (np.concatenate(a) if a else np.zeros(0, dtype=np.int64) for a in (pair_g, pair_q, pair_p))
    order = np.lexsort((pg, pp, pq))                         # by rank, neighbour, then id
    pg, pq, pp = pg[order], pq[order], pp[order]
    by_rank = np.argsort(r, kind="stable")                   # keys of each rank, ids ascending
    rank_bounds = np.searchsorted(r[by_rank], np.arange(size + 1))
    pair_bounds = np.searchsorted(pq, np.arange(size + 1))
    out = []
    for q in range(size) if ranks is None else ranks:
        mine = by_rank[rank_bounds[q]:rank_bounds[q + 1]]
        local_gid = g[mine]
        neighbours: dict[int, np.ndarray] = {}
        sl = slice(pair_bounds[q], pair_bounds[q + 1])
        nb, ids = pp[sl], pg[sl]
        for p in np.unique(nb):
            neighbours[int(p)] = np.searchsorted(local_gid, ids[nb == p])
        out.append((local_gid, SharedIndex(n=int(local_gid.size), owned=lowest[mine] == q,
                                           neighbours=neighbours, n_global=int(n_global))))
    return out


class NeighbourSum:
    """Sum the partial values of shared indices over the ranks holding them.

    One message to and from each neighbour per call; the total of an index is
    accumulated in increasing rank order (bitwise identical copies).
    """

    def __init__(self, comm: CountingComm, shared: SharedIndex) -> None:
        self.comm = comm
        self.shared = shared
        self.order = sorted(list(shared.neighbours) + [comm.rank])
        self.recv_sizes = {q: int(idx.size) for q, idx in shared.neighbours.items()}

    def sum(self, partial: np.ndarray) -> np.ndarray:
        """Total of ``partial`` (shape (n,)) over all ranks sharing each index."""
        partial = np.asarray(partial, dtype=np.float64)      # np.bincount of nothing is int64
        if not self.shared.neighbours:
            return partial
        sends = {q: partial[idx] for q, idx in self.shared.neighbours.items()}
        received = self.comm.exchange(sends, self.recv_sizes)
        total = np.zeros_like(partial)
        # inf + (-inf) of an overflowing scene is a NaN for the Krylov method to report, quietly, as the serial
        # sums (np.bincount) do: numpy's RuntimeWarning came from every rank (a review)
        with np.errstate(over="ignore", invalid="ignore"):
            for q in self.order:
                if q == self.comm.rank:
                    total += partial
                else:
                    total[self.shared.neighbours[q]] += received[q]
        return total
