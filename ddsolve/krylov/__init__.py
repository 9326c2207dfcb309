"""Krylov solvers: projected PCG with Lanczos condition estimates, and PCR.

Section 1.3 of Lee (2009): :func:`pcg` (Figure 1.2) for symmetric positive
definite problems, :func:`pcr` (Figure 1.3) for symmetric indefinite ones;
both accept an SPD inverse preconditioner ``M`` and an orthogonal projection
``P`` (FETI). They are thin wrappers of the classes :class:`PCG` and
:class:`PCR`, which write only their recurrences; :class:`KrylovSolver` does
the bookkeeping, the stopping test and the convergence and restart policies of
:mod:`ddsolve.krylov.convergence` (:data:`TRUE_RESIDUAL_FACTOR`,
:func:`attained`). :func:`lanczos_extreme_eigenvalues` turns the PCG
coefficients into estimates of the extreme eigenvalues of the preconditioned
operator.
"""
from .base import KrylovSolver
from .convergence import RESTART_FACTOR, TRUE_RESIDUAL_FACTOR, attained, norm2
from .lanczos import lanczos_extreme_eigenvalues
from .pcg import PCG, pcg
from .pcr import PCR, pcr
from .result import KrylovResult

__all__ = [
           "PCG",
           "PCR",
           "RESTART_FACTOR",
           "TRUE_RESIDUAL_FACTOR",
           "KrylovResult",
           "KrylovSolver",
           "attained",
           "lanczos_extreme_eigenvalues",
           "norm2",
           "pcg",
           "pcr",
]
