"""Krylov solvers: projected PCG with Lanczos condition estimates, and PCR.

Section 1.3 of Lee (2009): :func:`pcg` (Figure 1.2) for symmetric positive
definite problems, :func:`pcr` (Figure 1.3) for symmetric indefinite ones;
both accept an SPD inverse preconditioner ``M`` and an orthogonal projection
``P`` (FETI). :func:`lanczos_extreme_eigenvalues` turns the PCG coefficients
into estimates of the extreme eigenvalues of the preconditioned operator.
"""
from .lanczos import lanczos_extreme_eigenvalues
from .pcg import pcg
from .pcr import pcr
from .result import KrylovResult

__all__ = ["pcg", "pcr", "lanczos_extreme_eigenvalues", "KrylovResult"]
