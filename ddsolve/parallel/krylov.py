"""PCG with a distributed inner product: the serial recurrence, global reductions.

:class:`DistributedPCG` is :class:`~ddsolve.krylov.pcg.PCG` with the
reduction hooks (inner, inners, l2norm, absmax) of :class:`~ddsolve.krylov.base.KrylovSolver` replaced by
Allreduce over the indices each rank owns (:class:`~ddsolve.parallel.comm.SharedIndex`).
Vectors are rank-local, with consistent copies of shared indices (the operators
end with :class:`~ddsolve.parallel.comm.NeighbourSum`), so every rank runs the
same recurrence with the same scalars; the iteration counts are the serial ones.
Per iteration: 3 Allreduces (<p, q>, ||r||, <r, z>). :class:`DistributedPCR` is
:class:`~ddsolve.krylov.pcr.PCR` with the same hooks (the hybrid method): 3 Allreduces per
iteration of its two-term recurrence in the l2 norm (<A p, M A p>, ||r||, and <z, A z> with the
pivot test's ||z||, ||A z|| summed together by the ``inners`` hook).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..krylov.convergence import _DOT_MIN
from ..krylov.pcg import PCG
from ..krylov.pcr import PCR
from ..krylov.result import KrylovResult
from .comm import CountingComm

__all__ = ["DistributedPCG", "DistributedPCR", "DistributedReductions", "IterationCounter", "Reductions",
           "distributed_pcg"]


class Reductions:
    """Inner product, 2-norm and max-norm of rank-local vectors over all ranks.

    Parameters
    ----------
    comm : CountingComm
    owned : ndarray of bool, shape (n,)
        Entries counted in reductions (each shared entry on exactly one rank).
    """

    def __init__(self, comm: CountingComm, owned: np.ndarray) -> None:
        self.comm = comm
        self.owned = np.asarray(owned, dtype=bool)

    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        o = self.owned
        with np.errstate(over="ignore", invalid="ignore"):     # inf is handled by l2norm's rescaling, quietly
            return self.comm.allreduce_scalar(float(np.dot(a[o], b[o])))   # as serial (no RuntimeWarning)

    def inners(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> list[float]:
        """``[<a, b> for (a, b) in pairs]`` over all ranks in one Allreduce (the values of :meth:`inner`)."""
        o = self.owned
        with np.errstate(over="ignore", invalid="ignore"):
            local = np.array([np.dot(a[o], b[o]) for a, b in pairs], dtype=np.float64)
        return [float(x) for x in self.comm.allreduce_sum(local)]

    def l2norm(self, v: np.ndarray) -> float:
        d = self.inner(v, v)
        if _DOT_MIN <= d < math.inf or v.size == 0:
            return math.sqrt(d)
        scale = self.absmax(v)            # tiny or huge entries: scale by the global max |v_i|
        if not (0.0 < scale < math.inf):
            return scale if not math.isnan(scale) else math.nan
        return scale * math.sqrt(self.inner(v / scale, v / scale))

    def absmax(self, v: np.ndarray) -> float:
        """Global max |v_i|; a NaN anywhere gives inf on every rank (the same on all ranks)."""
        local = float(np.max(np.abs(v))) if v.size else 0.0
        return self.comm.allreduce_scalar(math.inf if math.isnan(local) else local, op="max")


class DistributedReductions:
    """The reduction hooks of :class:`~ddsolve.krylov.base.KrylovSolver` over ranks (:class:`Reductions`).

    Mixed in before a serial solver class; ``comm`` and ``owned`` (the entries counted in
    reductions) are keyword arguments of the constructor.
    """

    def __init__(self, A: Any, b: Any, x0: Any = None, *, comm: CountingComm, owned: np.ndarray,
                 **kwargs: Any) -> None:
        self.comm = comm
        self.reductions = Reductions(comm, owned)
        self.owned = self.reductions.owned
        super().__init__(A, b, x0, **kwargs)

    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        return self.reductions.inner(a, b)

    def inners(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> list[float]:
        return self.reductions.inners(pairs)

    def l2norm(self, v: np.ndarray) -> float:
        return self.reductions.l2norm(v)

    def absmax(self, v: np.ndarray) -> float:
        return self.reductions.absmax(v)


class DistributedPCG(DistributedReductions, PCG):
    """:class:`PCG` on rank-local vectors; ``owned`` marks the entries counted in reductions."""

    name = "pcg[mpi]"


class DistributedPCR(DistributedReductions, PCR):
    """:class:`PCR` on rank-local vectors (both recurrences use the reduction hooks)."""

    name = "pcr[mpi]"


class IterationCounter:
    """Messages, bytes and reductions of this rank per Krylov iteration (a ``callback``).

    Counted in the steady state: between the ends of the first and of the last iteration;
    the whole solve over its iterations if there are fewer than two.
    """

    def __init__(self, comm: CountingComm) -> None:
        self.comm = comm
        self.start = comm.counters.snapshot()
        self.marks: list[tuple[int, int, int]] = []

    def __call__(self, _x: Any) -> None:
        self.marks.append(self.comm.counters.snapshot())

    def per_iteration(self, iterations: int) -> tuple:
        marks = self.marks
        if len(marks) >= 2:
            return tuple((b_ - a_) / (len(marks) - 1) for a_, b_ in zip(marks[0], marks[-1]))
        end = self.comm.counters.snapshot()
        return tuple((b_ - a_) / max(iterations, 1) for a_, b_ in zip(self.start, end))


def distributed_pcg(A: Any, b: Any, x0: Any = None, *, comm: CountingComm, owned: np.ndarray, rtol: float = 1e-6,
                    maxiter: int | None = None, M: Any = None, P: Any = None,
                    cond: bool = False) -> tuple[KrylovResult, tuple]:
    """:func:`ddsolve.krylov.pcg` with a distributed inner product (see :class:`DistributedPCG`).

    Returns
    -------
    result : KrylovResult
    per_iteration : tuple of float
        (messages, bytes, allreduces) of this rank per iteration (:class:`IterationCounter`).
    """
    counter = IterationCounter(comm)
    kr = DistributedPCG(A, b, x0, comm=comm, owned=owned, rtol=rtol, maxiter=maxiter, M=M, P=P, cond=cond,
                        callback=counter).solve()
    return kr, counter.per_iteration(kr.iterations)
