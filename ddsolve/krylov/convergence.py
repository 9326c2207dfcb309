"""The one convergence policy of the Krylov solvers, and norms safe against under/overflow.

A Krylov solve stops on its *recursively updated* residual; it is reported as
converged only if the residual *recomputed* from the returned iterate meets
the tolerance within :data:`TRUE_RESIDUAL_FACTOR` and every value is finite
(:func:`attained_residual`, used by :class:`~ddsolve.krylov.base.KrylovSolver`).
A restarted solve (:meth:`~ddsolve.krylov.base.KrylovSolver.restarted`)
restarts a cycle whose recomputed residual exceeds :data:`RESTART_FACTOR` times
the threshold. :func:`attained` applies the rule to a finished result against
a caller's ``rtol`` (what :func:`ddsolve.solve` reports).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg.blas import dnrm2

from .result import KrylovResult

__all__ = [
    "RESTART_FACTOR",
    "TRUE_RESIDUAL_FACTOR",
    "attained",
    "attained_residual",
    "norm2",
    "not_attained_reason",
]

#: A Krylov solve counts as converged only if the residual recomputed from its
#: final iterate is within this factor of the tolerance rtol ||r_0||.
TRUE_RESIDUAL_FACTOR = 10.0
#: A restarted solve (the hybrid's PCR) accepts a cycle only if its recomputed
#: residual is within this factor of the threshold; otherwise it restarts.
RESTART_FACTOR = 2.0

# sqrt(<v, v>) is exact to rounding when <v, v> lies in this range: no square
# overflowed (the sum is finite) and the squares that underflowed (< 2^-1022
# each) are below 2^-1022 * n / 2^-880 <= 2^-100 relative for any n < 2^42.
_DOT_MIN = 2.0 ** -880


def norm2(v: np.ndarray) -> float:
    """Euclidean norm of a 1-D float64 array, safe against overflow and underflow.

    The fast path ``sqrt(<v, v>)`` (one BLAS dot, the same number as before)
    is taken when ``<v, v>`` is finite and not tiny; otherwise the scaled BLAS
    ``dnrm2`` is used (like LAPACK/BLAS nrm2), so entries of size 1e-170 or
    1e+170 give the right norm instead of 0 or inf. NaN in ``v`` gives NaN;
    an infinite entry gives inf.
    """
    if v.size == 0:
        return 0.0
    d = float(np.vdot(v, v))       # the BLAS dot of np.dot, without numpy's overflow warning
    if _DOT_MIN <= d < math.inf:
        return math.sqrt(d)
    return float(dnrm2(np.ascontiguousarray(v, dtype=np.float64)))


#: A dual method's solve that met its Krylov rule is reported converged only if the estimated relative
#: energy error of its u (an upper bound: :func:`ddsolve.dd.check.energy_error_estimate`,
#: ``DDInverse.error_estimate``) is at most min(ERROR_FACTOR rtol, ERROR_CAP). On smooth problems and with
#: robust scalings the estimate is 1-2x the error and the error 0.1-3 rtol; with coefficient jumps that
#: the scaling does not handle the dual rules leave errors of 1e2-1e5 rtol (docs/methods.md).
ERROR_FACTOR = 100.0
ERROR_CAP = 0.1
#: The estimate's own rounding level (r = A u - f in double precision): at rtol 1e-12 a solution that
#: agreed with a direct solve to 1e-9 read 3.4e-10 (P1, coefficient stripes 1 / 1e6, deluxe FETI-DP).
ERROR_FLOOR = 1e-9


def error_limit(rtol: float) -> float:
    """max(min(ERROR_FACTOR rtol, ERROR_CAP), ERROR_FLOOR): the largest error estimate a converged solve may have."""
    return max(min(ERROR_FACTOR * rtol, ERROR_CAP), ERROR_FLOOR)


def not_attained_reason(true_rel: float, rec_rel: float, factor: float, rtol: float) -> str:
    """The one-line reason of a solve whose recomputed residual misses the tolerance."""
    return (f"tolerance not attained: recomputed ||r||/||r0|| = {true_rel:.1e} > "
            f"{factor:g} rtol = {factor * rtol:.1e} although the recursive "
            f"residual reached {rec_rel:.1e} (rtol below the attainable accuracy)")


def attained_residual(true_residual: float | None, threshold: float,
                      factor: float = TRUE_RESIDUAL_FACTOR) -> bool:
    """Whether a recomputed residual meets ``threshold`` within ``factor`` (False for NaN/inf/None)."""
    return (true_residual is not None and math.isfinite(true_residual)
            and true_residual <= factor * threshold)


def attained(kr: KrylovResult, rtol: float) -> tuple[bool, str]:
    """Whether a converged Krylov solve also meets ``rtol`` by its recomputed residual.

    At a tolerance below the attainable accuracy (round-off, e.g. ``rtol =
    1e-20``) the recursively updated residual of PCG keeps decreasing while the
    true residual ``||P (b - A x)||`` stagnates; the solve must then not report
    convergence. (The solvers of :mod:`ddsolve.krylov` apply this rule
    themselves against their threshold ``max(rtol ||r_0||, atol)``; this
    function checks a result against a caller's ``rtol``.)

    Returns
    -------
    ok : bool
        False if ``kr.converged`` but ``kr.true_residual > TRUE_RESIDUAL_FACTOR
        rtol ||r_0||`` (or is not finite).
    reason : str
        ``kr.reason``, extended by why the solve was not accepted.
    """
    if not kr.converged or kr.true_residual is None or kr.residuals.size == 0:
        return kr.converged, kr.reason
    r0 = float(kr.residuals[0])
    if not math.isfinite(kr.true_residual):
        return False, f"non-finite recomputed residual ({kr.true_residual}) although {kr.reason}"
    if kr.true_residual <= TRUE_RESIDUAL_FACTOR * rtol * r0:
        return True, kr.reason
    rel = kr.true_residual / r0 if r0 > 0 else math.inf
    rec = float(kr.residuals[-1]) / r0 if r0 > 0 else math.inf
    return False, not_attained_reason(rel, rec, TRUE_RESIDUAL_FACTOR, rtol)
