"""Exact power-of-two rescaling of a quadratic program, so that MPRGP and SMALBE are scale-invariant.

The problem ``min 1/2 x^T A x - b^T x`` (with bounds ``x >= l`` and equalities
``B_E x = c``) is solved in the units

.. math::

    A = 2^{a} A', \\quad b = 2^{e} b', \\quad x = 2^{e - a} x', \\quad l = 2^{e - a} l', \\quad
    c = 2^{e - a} c', \\quad \\mu = 2^{e} \\mu', \\quad \\rho = 2^{a} \\rho',

with ``2^a`` the power of two nearest below ``||A||`` and ``2^e`` that of ``||b||``, so that
``||A'||`` and ``||b'||`` lie in ``[1, 2)``. The gradient scales like ``b``
(``A x - b = 2^e (A' x' - b')``), the steplength like ``1/A`` and the
Lagrangian like ``2^{2e - a}``. A multiplication by a power of two is exact in
binary floating point (away from overflow and subnormals), and every operation
of the iterations (sums, products, quotients, square roots) commutes with it
exactly, so the scaled iteration computes the *same numbers* times powers of two:
same steps, same iteration counts, bit-identical results after scaling back, at
any scale where the unscaled iteration did not over- or underflow. Where it did
(``p^T A p`` of a gradient of size 1e150 overflows; of size 1e-150 underflows),
the scaled iteration works with quantities of size ~1 and reproduces the
iteration of the problem at unit scale.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..krylov.convergence import norm2

__all__ = ["QPScaling", "exponent"]


def exponent(value: float) -> int:
    """``k`` with ``2^k <= value < 2^(k+1)`` for a finite ``value > 0``; 0 otherwise."""
    if not (value > 0.0 and math.isfinite(value)):
        return 0
    return math.frexp(value)[1] - 1


@dataclass(frozen=True)
class QPScaling:
    """The exponents ``a`` (Hessian) and ``e`` (linear term) of the rescaling (module docstring).

    Attributes
    ----------
    a : int
        ``A = 2^a A'``.
    e : int
        ``b = 2^e b'``; ``x = 2^(e - a) x'``.
    """

    a: int = 0
    e: int = 0

    @classmethod
    def of(cls, norm_A: float, b: np.ndarray, *xs: np.ndarray) -> "QPScaling":
        """Exponents from ``||A||`` and ``||b||``; for ``b = 0`` from the finite entries of ``xs``
        (start vector, bounds: quantities of the units of ``x``) as ``||b|| ~ ||A|| ||x||``."""
        a = exponent(norm_A)
        norm_b = norm2(b)
        if norm_b > 0.0 and math.isfinite(norm_b):
            return cls(a, exponent(norm_b))
        size = max((float(np.abs(v[np.isfinite(v)]).max(initial=0.0)) for v in xs), default=0.0)
        return cls(a, exponent(size) + a if size > 0.0 else a)

    # ---------------------------------------------------------------- scalars
    @property
    def x(self) -> int:
        """Exponent of ``x`` (and ``l``, ``c``, ``B_E x - c``): ``e - a``."""
        return self.e - self.a

    @staticmethod
    def up(value: float | np.ndarray, k: int) -> float | np.ndarray:
        """``value * 2^k`` exactly (``-inf`` bounds stay ``-inf``; a result beyond the range is inf or 0)."""
        with np.errstate(over="ignore", under="ignore"):
            if isinstance(value, np.ndarray):
                return np.ldexp(value, k)
            return float(np.ldexp(float(value), k))
