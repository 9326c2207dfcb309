"""Convex quadratic programming with bound and equality constraints (Lee's thesis, Chapter 6).

* :func:`mprgp` -- MPRGP for ``min 1/2 x^T A x - b^T x  s.t.  x >= lb`` (Figure 6.6).
* :func:`smalbe` -- SMALBE for ``min 1/2 x^T A x - b^T x  s.t.  x >= lb, BE x = c`` (Figure 6.7).
* :class:`QPResult` -- their common result.
"""
from .mprgp import mprgp
from .norm import estimate_norm
from .result import QPResult
from .smalbe import smalbe

__all__ = ["QPResult", "estimate_norm", "mprgp", "smalbe"]
