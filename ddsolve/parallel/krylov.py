"""PCG with a distributed inner product: the serial recurrence, global reductions.

:class:`DistributedPCG` is :class:`~ddsolve.krylov.pcg.PCG` with the three
reduction hooks of :class:`~ddsolve.krylov.base.KrylovSolver` replaced by
Allreduce over the indices each rank owns (:class:`~ddsolve.parallel.comm.SharedIndex`).
Vectors are rank-local, with consistent copies of shared indices (the operators
end with :class:`~ddsolve.parallel.comm.NeighbourSum`), so every rank runs the
same recurrence with the same scalars; the iteration counts are the serial ones.
Per iteration: 3 Allreduces (<p, q>, ||r||, <r, z>).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..krylov.convergence import _DOT_MIN
from ..krylov.pcg import PCG
from ..krylov.result import KrylovResult
from .comm import CountingComm

__all__ = ["DistributedPCG", "distributed_pcg"]


class DistributedPCG(PCG):
    """:class:`PCG` on rank-local vectors; ``owned`` marks the entries counted in reductions."""

    name = "pcg[mpi]"

    def __init__(self, A: Any, b: Any, x0: Any = None, *, comm: CountingComm, owned: np.ndarray,
                 **kwargs: Any) -> None:
        self.comm = comm
        self.owned = np.asarray(owned, dtype=bool)
        super().__init__(A, b, x0, **kwargs)

    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        o = self.owned
        return self.comm.allreduce_scalar(float(np.dot(a[o], b[o])))

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

def distributed_pcg(A: Any, b: Any, x0: Any = None, *, comm: CountingComm, owned: np.ndarray, rtol: float = 1e-6,
                    maxiter: int | None = None, M: Any = None, P: Any = None,
                    cond: bool = False) -> tuple[KrylovResult, tuple]:
    """:func:`ddsolve.krylov.pcg` with a distributed inner product (see :class:`DistributedPCG`).

    Returns
    -------
    result : KrylovResult
    per_iteration : tuple of float
        (messages, bytes, allreduces) of this rank per iteration in the steady state (between
        the ends of the first and of the last iteration; the whole solve over its iterations if
        there are fewer than two).
    """
    marks: list[tuple[int, int, int]] = []
    start = comm.counters.snapshot()
    kr = DistributedPCG(A, b, x0, comm=comm, owned=owned, rtol=rtol, maxiter=maxiter, M=M, P=P, cond=cond,
                        callback=lambda _x: marks.append(comm.counters.snapshot())).solve()
    if len(marks) >= 2:
        per = tuple((b_ - a_) / (len(marks) - 1) for a_, b_ in zip(marks[0], marks[-1]))
    else:
        end = comm.counters.snapshot()
        per = tuple((b_ - a_) / max(kr.iterations, 1) for a_, b_ in zip(start, end))
    return kr, per
