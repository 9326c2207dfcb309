"""Preconditioned conjugate residuals (Section 1.3.2 of Lee 2009), optionally projected.

For symmetric, possibly indefinite ``A`` (saddle-point systems) and an SPD
(inverse) preconditioner ``M``. The iterate ``x_k`` minimises the ``M``-norm of
the residual, ``||M^{1/2} (b - A x)||_2``, over ``x_0 + K_k(M A, M r_0)``
(Lemma 1.3.2 of the thesis; Saad, Sec. 9.5; Toselli & Widlund, App. C.6).

Two mathematically equivalent recurrences are used:

* the two-term conjugate residual recurrences (CR applied to ``M A`` in the
  ``M^{-1}`` inner product), which carry ``p``, ``A p`` and ``M A p``. They are
  the default because, like PCG, their recursively updated residual stays
  close to the true one at tight tolerances. Their scalar ``<z, A z>`` may
  vanish when ``A`` is indefinite;
* the three-term recurrence of Figure 1.3 of the thesis (Klawonn & Widlund),
  whose only denominators are ``<A p, M A p> > 0``, so it cannot break down for
  nonsingular ``A``. It takes over, restarted from the current iterate, when
  ``<z, A z>`` is (numerically) zero.
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .pcg import (
    _apply,
    _converged_reason,
    _initial_checks,
    _initial_residual,
    _maxiter_reason,
    _norm,
    _readonly_view,
    _setup,
    _Setup,
    _true_residual,
)
from .result import KrylovResult

__all__ = ["pcr"]

logger = logging.getLogger(__name__)

#: ``|<z, A z>| <= _CR_PIVOT_TOL * ||z|| * ||A z||`` hands over to the three-term
#: recurrence (the two-term CR would divide by a numerically zero pivot).
_CR_PIVOT_TOL = 1e-8

# outcomes of one recurrence
_CONVERGED, _MAXITER, _BREAKDOWN, _SWITCH = "converged", "maxiter", "breakdown", "switch"


class _PCRState:
    """Iterate, residual and bookkeeping shared by the two recurrences."""

    def __init__(self, s: _Setup, r: np.ndarray, rnorm0: float, threshold: float,
                 matvecs: int, callback: Callable[[np.ndarray], Any] | None) -> None:
        self.s = s
        self.x = s.x
        self.r = r
        self.rnorm0 = rnorm0
        self.threshold = threshold
        self.matvecs = matvecs
        self.iterations = 0
        self.residuals = [rnorm0]
        self.reason = ""
        self.tmp = np.empty_like(s.x)
        self.callback = callback
        self.x_view = _readonly_view(self.x) if callback is not None else None
        self.debug = logger.isEnabledFor(logging.DEBUG)

    def op(self, v: np.ndarray) -> np.ndarray:
        """``P A v`` (counts one operator application)."""
        self.matvecs += 1
        w = _apply(self.s.A, v)
        return w if self.s.P is None else _apply(self.s.P, w)

    def precondition(self, v: np.ndarray) -> np.ndarray:
        """``P M v`` (a fresh array)."""
        z = v.copy() if self.s.M is None else _apply(self.s.M, v)
        return z if self.s.P is None else _apply(self.s.P, z)

    def step(self, step: float, p: np.ndarray, ap: np.ndarray) -> str | None:
        """``x += step p``, ``r -= step A p``; record, call back, test convergence.

        Returns None to continue, or ``_CONVERGED`` / ``_MAXITER`` / ``_BREAKDOWN``
        (with ``self.reason`` set).
        """
        tmp = self.tmp
        np.multiply(p, step, out=tmp)
        self.x += tmp
        np.multiply(ap, step, out=tmp)
        self.r -= tmp
        rnorm = _norm(self.r)
        self.residuals.append(rnorm)
        self.iterations += 1
        k = self.iterations
        if self.debug:
            logger.debug("pcr it %d: ||r||/||r0|| = %.3e", k, rnorm / self.rnorm0)
        if self.callback is not None:
            self.callback(self.x_view)
        if not math.isfinite(rnorm):
            self.reason = f"breakdown: non-finite residual at iteration {k}"
            return _BREAKDOWN
        if rnorm <= self.threshold:
            self.reason = _converged_reason(rnorm, self.rnorm0, self.threshold)
            return _CONVERGED
        if k >= self.s.maxiter:
            self.reason = _maxiter_reason(self.s.maxiter, rnorm, self.rnorm0, self.threshold)
            return _MAXITER
        return None

    def breakdown_denominator(self, value: float) -> str:
        self.reason = (f"breakdown: <A p, M A p> = {value:.3e} at iteration "
                       f"{self.iterations + 1} (A singular, M not positive definite, "
                       "or NaN/inf)")
        return _BREAKDOWN


def _two_term(st: _PCRState) -> str:
    """Conjugate residual recurrences for ``M A`` in the ``M^{-1}`` inner product::

        z_0 = M r_0,  p_0 = z_0,  A p_0 = A z_0,  rho_0 = <z_0, A z_0>
        alpha_k   = rho_k / <A p_k, M A p_k>
        x_{k+1}   = x_k + alpha_k p_k
        r_{k+1}   = r_k - alpha_k A p_k
        z_{k+1}   = z_k - alpha_k M A p_k
        rho_{k+1} = <z_{k+1}, A z_{k+1}>,   beta_k = rho_{k+1} / rho_k
        p_{k+1}   = z_{k+1} + beta_k p_k
        A p_{k+1} = A z_{k+1} + beta_k A p_k,   M A p_{k+1} = M (A p_{k+1})

    One operator (``A z``) and one preconditioner (``M A p``) application per
    iteration. Returns ``_SWITCH`` when ``rho`` is numerically zero.
    """
    tmp = st.tmp
    z = st.precondition(st.r)
    az = st.op(z)
    rho = float(np.dot(z, az))
    if not math.isfinite(rho):
        st.reason = f"breakdown: non-finite <z, A z> at iteration {st.iterations + 1}"
        return _BREAKDOWN
    if abs(rho) <= _CR_PIVOT_TOL * _norm(z) * _norm(az):
        return _SWITCH
    p = z.copy()
    ap = az
    map_ = st.precondition(ap)
    while True:
        den = float(np.dot(ap, map_))
        if not (den > 0.0 and math.isfinite(den)):
            return st.breakdown_denominator(den)
        alpha = rho / den
        if not math.isfinite(alpha):
            st.reason = f"breakdown: non-finite step length at iteration {st.iterations + 1}"
            return _BREAKDOWN
        outcome = st.step(alpha, p, ap)
        if outcome is not None:
            return outcome
        np.multiply(map_, alpha, out=tmp)
        z -= tmp
        az = st.op(z)
        rho_new = float(np.dot(z, az))
        if not math.isfinite(rho_new):
            st.reason = f"breakdown: non-finite <z, A z> at iteration {st.iterations + 1}"
            return _BREAKDOWN
        if abs(rho_new) <= _CR_PIVOT_TOL * _norm(z) * _norm(az):
            return _SWITCH
        beta = rho_new / rho
        rho = rho_new
        p *= beta
        p += z
        ap *= beta
        ap += az
        map_ = st.precondition(ap)


def _three_term(st: _PCRState) -> str:
    """Figure 1.3 of the thesis (Klawonn-Widlund PCR), restarted at the current ``x``::

        p_0 = M r,  w_0 = A p_0,  v_0 = M w_0          (w_k = A p_k, v_k = M A p_k)
        lambda  = <r, v_{k-1}> / <w_{k-1}, v_{k-1}>
        x      += lambda p_{k-1},   r -= lambda w_{k-1}
        t       = A v_{k-1}
        a0      = <t, v_{k-1}> / <w_{k-1}, v_{k-1}>,  a1 = <t, v_{k-2}> / <w_{k-2}, v_{k-2}>
        p_k     = v_{k-1} - a0 p_{k-1} - a1 p_{k-2},  w_k = t - a0 w_{k-1} - a1 w_{k-2}
        v_k     = M w_k,   then (p_k, w_k, v_k) /= sqrt(<w_k, v_k>)

    The ``A p_k`` are ``M``-orthogonal; the normalisation keeps the recurrence
    from overflowing (it grows like ``||M A||^k`` otherwise). One operator and
    one preconditioner application per iteration.
    """
    tmp = st.tmp
    p = st.precondition(st.r)
    w = st.op(p)
    v = st.precondition(w)
    d = float(np.dot(w, v))
    if not (d > 0.0 and math.isfinite(d)):
        return st.breakdown_denominator(d)
    scale = 1.0 / math.sqrt(d)
    p *= scale
    w *= scale
    v *= scale
    p_prev = np.zeros_like(p)  # p_{k-2}; its buffer receives the next direction
    w_prev: np.ndarray | None = None
    v_prev: np.ndarray | None = None
    while True:
        lam = float(np.dot(st.r, v))  # <w, v> = 1 after normalisation
        if not math.isfinite(lam):
            st.reason = f"breakdown: non-finite step length at iteration {st.iterations + 1}"
            return _BREAKDOWN
        outcome = st.step(lam, p, w)
        if outcome is not None:
            return outcome
        t = st.op(v)
        a0 = float(np.dot(t, v))
        a1 = float(np.dot(t, v_prev)) if v_prev is not None else 0.0
        if not (math.isfinite(a0) and math.isfinite(a1)):
            st.reason = ("breakdown: non-finite orthogonalisation coefficient at "
                         f"iteration {st.iterations + 1}")
            return _BREAKDOWN
        p_prev *= -a1  # p_prev <- v - a0 p - a1 p_prev, in place
        np.multiply(p, a0, out=tmp)
        p_prev -= tmp
        p_prev += v
        np.multiply(w, a0, out=tmp)  # t <- t - a0 w - a1 w_prev (= A p_k)
        t -= tmp
        if w_prev is not None:
            np.multiply(w_prev, a1, out=tmp)
            t -= tmp
        v_new = st.precondition(t)
        d = float(np.dot(t, v_new))
        if not (d > 0.0 and math.isfinite(d)):
            return st.breakdown_denominator(d)
        scale = 1.0 / math.sqrt(d)
        p_prev *= scale
        t *= scale
        v_new *= scale
        p, p_prev = p_prev, p
        w_prev, w = w, t
        v_prev, v = v, v_new


def pcr(
    A: Any,
    b: Any,
    x0: Any = None,
    *,
    rtol: float = 1e-6,
    atol: float = 0.0,
    maxiter: int | None = None,
    M: Any = None,
    P: Any = None,
    callback: Callable[[np.ndarray], Any] | None = None,
) -> KrylovResult:
    """Solve ``A x = b`` (``A`` symmetric, maybe indefinite) by preconditioned CR.

    The preconditioned conjugate residual method of Section 1.3.2 / Figure 1.3
    of Lee (2009): ``x_k`` minimises ``||r||_M = <r, M r>^{1/2}`` over
    ``x_0 + K_k(M A, M r_0)``, so by Lemma 1.3.2 the ``M``-norm of the residual
    decreases monotonically at a rate governed by
    ``max|lambda(MA)| / min|lambda(MA)|``. It is computed with the two-term CR
    recurrences (``p``, ``A p`` and ``M A p`` all carried, see ``_two_term``),
    which keep the recursive residual accurate down to tight tolerances; if
    the CR scalar ``<z, A z>`` becomes numerically zero (possible because ``A``
    is indefinite) the iteration continues from the current iterate with the
    breakdown-free three-term recurrence printed in Figure 1.3 of the thesis.
    Either way each iteration costs one operator and one preconditioner
    application.

    With the orthogonal projection ``P`` the operator is ``P A``, the
    preconditioner ``P M`` and the residual ``r = P (b - A x)``, so
    ``x - x_0`` stays in ``range(P)``.

    Parameters
    ----------
    A : ndarray, sparse matrix, LinearOperator or object with ``.matvec``/``.shape``
        Symmetric operator, shape (n, n), nonsingular (on ``range(P)``).
    b : array_like, shape (n,)
        Right-hand side.
    x0 : array_like, shape (n,), optional
        Initial guess (zero by default).
    rtol, atol : float
        Stop when ``||r_k||_2 <= max(rtol * ||r_0||_2, atol)`` (Euclidean norm,
        which, unlike ``||r||_M``, need not decrease monotonically). At least
        one must be > 0.
    maxiter : int, optional
        Maximum number of iterations, ``10 * n`` by default.
    M : operator, shape (n, n), optional
        SPD *inverse* preconditioner, ``z = M r`` (as in scipy); identity by
        default.
    P : operator, shape (n, n), optional
        Orthogonal projection (symmetric, ``P^2 = P``); identity by default.
    callback : callable, optional
        ``callback(xk)`` after each iteration with a read-only view of the
        current iterate, shape (n,).

    Returns
    -------
    KrylovResult
        ``x`` shape (n,), ``residuals`` shape (iterations + 1,) (recursively
        updated ``||r_k||_2``), ``true_residual`` = ``||P (b - A x)||_2``
        recomputed at the end (one operator application, counted in
        ``matvecs``). At very tight tolerances on ill-conditioned problems the
        true residual can exceed the recursive one (rounding in the
        recurrences); compare the two. ``lambda_min``, ``lambda_max`` and
        ``cond`` are None. Non-convergence and breakdown
        (``<A p, M A p> <= 0``, i.e. ``A`` singular or ``M`` not SPD, or
        NaN/inf) give ``converged=False`` and a one-line ``reason``; ``x`` is
        then the last finite iterate.

    Raises
    ------
    InputError
        (a ``ValueError``) for invalid arguments: shape mismatch, both
        ``rtol`` and ``atol`` <= 0, ``maxiter < 1``, an unusable operator.
    """
    s = _setup(A, b, x0, rtol, atol, maxiter, M, P)
    t0 = time.perf_counter()
    r, matvecs = _initial_residual(s)
    early, rnorm0, threshold = _initial_checks(s, r, matvecs, t0)
    if early is not None:
        return early

    st = _PCRState(s, r, rnorm0, threshold, matvecs, callback)
    outcome = _two_term(st)
    if outcome == _SWITCH:
        logger.debug("pcr: <z, A z> ~ 0 at iteration %d, switching to the three-term "
                     "recurrence (Figure 1.3)", st.iterations + 1)
        outcome = _three_term(st)

    true_res = _true_residual(s, st.x)
    st.matvecs += 1
    seconds = time.perf_counter() - t0
    logger.debug("pcr: %s (%d iterations, %.3g s)", st.reason, st.iterations, seconds)
    return KrylovResult(
        x=st.x, converged=outcome == _CONVERGED, reason=st.reason,
        iterations=st.iterations, residuals=np.asarray(st.residuals),
        matvecs=st.matvecs, seconds=seconds, true_residual=true_res,
    )
