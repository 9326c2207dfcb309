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

The stopping rule measures the residual either in the Euclidean norm
(``norm="l2"``, the rule of Section 4.4 of the thesis and scipy's) or in the
norm the iteration minimises, ``||r||_M = <r, M r>^{1/2}`` (``norm="M"``). For
a block-diagonal preconditioner such as (4.11) of the thesis the latter is
invariant under a rescaling of the blocks (e.g. forces ~ rho against
displacements ~ 1/rho), which ``||r||_2`` is not. Both recurrences carry
``z = M r`` recursively (``z -= step * M A p``), so ``||r||_M`` costs one dot
product per iteration and one preconditioner application at the start.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any, Literal

import numpy as np

from ..errors import InputError
from ..options import NORMS  # Euclidean, or <r, M r>^{1/2} with M the preconditioner
from .base import BREAKDOWN, KrylovSolver, apply, as_matvec
from .convergence import _DOT_MIN, norm2
from .result import KrylovResult

__all__ = ["NORMS", "PCR", "pcr"]

logger = logging.getLogger(__name__)

#: ``|<z, A z>| <= _CR_PIVOT_TOL * ||z|| * ||A z||`` hands over to the three-term
#: recurrence (the two-term CR would divide by a numerically zero pivot). For
#: ``norm="M"`` the norms are those of the M-geometry, ``||z||_{M^-1} = <r, M r>^{1/2}``
#: and ``||A z||_M``, so the test is invariant under block scalings of the unknowns
#: (rho -> s rho in a saddle-point system); see :func:`_cr_pivot`.
_CR_PIVOT_TOL = 1e-8
#: A negative ``<r, M r>`` within ``_ROUNDING * ||r|| ||M r||`` is rounding, not an
#: indefinite ``M``: its square root is taken of the absolute value.
_ROUNDING = 64 * float(np.finfo(float).eps)

#: outcome of the two-term recurrence when its pivot <z, A z> vanishes
_SWITCH = "switch"


def _m_norm(r: np.ndarray, z: np.ndarray, rz: float | None = None, inner: Any = None, norm: Any = None) -> float:
    """``<r, z>^{1/2}`` with ``z = M r``: the ``M``-norm of the residual.

    NaN when ``<r, z>`` (``rz`` if given) is negative beyond rounding (``M``
    not positive definite) or not finite; a negative value at rounding level
    counts by its modulus. ``inner``, ``norm``: the solver's reduction hooks
    (default ``np.dot`` and ``norm2``; a distributed solver passes its own).
    """
    if rz is None:
        rz = float(np.dot(r, z)) if inner is None else inner(r, z)
    if rz >= 0.0:
        return math.sqrt(rz)
    norm = norm2 if norm is None else norm
    if -rz <= _ROUNDING * norm(r) * norm(z):
        return math.sqrt(-rz)
    return math.nan


class PCR(KrylovSolver):
    """Projected preconditioned conjugate residuals, the recurrences of :func:`pcr`.

    Parameters are those of :class:`~ddsolve.krylov.base.KrylovSolver` and
    ``norm`` (``"l2"`` or ``"M"``, the stopping norm).
    """

    name = "pcr"

    def __init__(self, A: Any, b: Any, x0: Any = None, *, norm: Literal["l2", "M"] = "l2",
                 **kwargs: Any) -> None:
        if not isinstance(norm, str) or norm not in NORMS:
            raise InputError("norm", f"must be one of {', '.join(map(repr, NORMS))}, got {norm!r}")
        super().__init__(A, b, x0, **kwargs)
        #: stopping norm, "l2" or "M"
        self.norm = norm
        #: z = P M r, updated with r (always by the two-term recurrence, by the
        #: three-term one only for norm="M"); None when not carried
        self.z: np.ndarray | None = None

    @staticmethod
    def rhs_norm(b: np.ndarray, M: Any = None, norm: str = "l2") -> float:
        """``||b||_2``, or for ``norm="M"`` ``|<b, M b>|^{1/2}``, safe against under/overflow.

        The ``M``-norm is computed on ``2^k b`` with ``max |2^k b|`` of order
        one when ``b`` is far from that scale (exact; the result is divided by
        ``2^k``).
        """
        b = np.asarray(b, dtype=np.float64)
        if norm != "M":
            return norm2(b)
        if M is None:
            return norm2(b)
        matvec = as_matvec(M, b.size, "M")[0]
        amax = float(np.max(np.abs(b))) if b.size else 0.0
        scale = 1.0
        if 0.0 < amax < math.inf and not -64 <= math.frexp(amax)[1] <= 64:
            scale = math.ldexp(1.0, max(-1000, min(1000, -math.frexp(amax)[1])))
        bs = b * scale if scale != 1.0 else b
        bb = float(np.dot(bs, apply(matvec, bs, "M")))
        return float(np.sqrt(abs(bb))) / scale   # a negative <F, B^{-1} F> breaks down in pcr

    # ------------------------------------------------------------ hooks
    def initial_norm(self, r: np.ndarray) -> float:
        if self.norm != "M":
            return self.l2norm(r)
        self.z = self.precondition(r)
        return _m_norm(r, self.z, inner=self.inner, norm=self.l2norm)

    def initial_failure(self, rnorm0: float) -> tuple[str, float]:
        if self.norm != "M":
            return super().initial_failure(rnorm0)
        rz = self.inner(self.r, self.z)
        what = (f"<r0, M r0> = {rz:.3e} < 0 (M not positive definite)" if math.isfinite(rz)
                else "non-finite <r0, M r0> (NaN/inf in A, b, x0, M or P)")
        return f"breakdown: {what}", (math.sqrt(-rz) if math.isfinite(rz) else rnorm0)

    def true_residual(self, x: np.ndarray) -> float:
        """``||P (b - A x)||`` in the stopping norm; for ``"M"`` ``<r, P M r>^{1/2}``
        (one more preconditioner application; NaN if ``<r, M r>`` is clearly negative).
        """
        if self.norm != "M":
            return super().true_residual(x)
        r = self.b - apply(self.A, x)
        if self.P is not None:
            r = apply(self.P, r, "P")
        return _m_norm(r, self.precondition(r), inner=self.inner, norm=self.l2norm)

    def label(self, reason: str) -> str:
        """Name the ``M``-norm in a stopping reason (``||r||`` -> ``||r||_M``)."""
        if self.norm != "M":
            return reason
        return reason.replace("||r||/||r0||", "||r||_M/||r0||_M")

    # ------------------------------------------------------------ recurrence
    def iterate(self) -> str:
        outcome = _two_term(self)
        if outcome == _SWITCH:
            logger.debug("pcr: <z, A z> ~ 0 at iteration %d, switching to the three-term "
                         "recurrence (Figure 1.3)", self.iterations + 1)
            outcome = _three_term(self)
        return outcome

    def step(self, step: float, p: np.ndarray, ap: np.ndarray,
             map_: np.ndarray | None = None) -> str | None:
        """``x += step p``, ``r -= step A p``, ``z -= step M A p``; record, call back, test.

        ``map_`` (``P M A p``) is required while ``self.z`` is carried. The
        residual is measured in ``self.norm``. Returns None to continue, or
        CONVERGED / MAXITER / BREAKDOWN (with ``self.reason`` set).
        """
        tmp = self.tmp
        np.multiply(p, step, out=tmp)
        self.x += tmp
        np.multiply(ap, step, out=tmp)
        self.r -= tmp
        if self.z is not None:
            if map_ is None:  # pragma: no cover - internal invariant
                raise RuntimeError("pcr: M A p is needed to update z = M r")
            np.multiply(map_, step, out=tmp)
            self.z -= tmp
        if self.norm == "M":
            rz = self.inner(self.r, self.z)
            rnorm = _m_norm(self.r, self.z, rz, inner=self.inner, norm=self.l2norm)
            if math.isnan(rnorm) and math.isfinite(rz):
                # clearly negative <r, M r>: recorded by its modulus (a non-finite one is caught below)
                self.iterations += 1
                self.residuals.append(math.sqrt(-rz))
                return self.breakdown(f"breakdown: <r, M r> = {rz:.3e} < 0 at iteration "
                                      f"{self.iterations} (M not positive definite)")
        else:
            rnorm = self.l2norm(self.r)
        return self.advance(rnorm)

    def breakdown_denominator(self, value: float) -> str:
        return self.breakdown(f"breakdown: <A p, M A p> = {value:.3e} at iteration "
                              f"{self.iterations + 1} (A singular, M not positive definite, "
                              "or NaN/inf)")


def _cr_pivot(st: PCR, z: np.ndarray, az: np.ndarray) -> tuple[float, np.ndarray | None, bool]:
    """The CR pivot ``rho = <z, A z>``, ``P M A z`` (``norm="M"``, else None) and whether ``rho`` is
    numerically zero (the cosine test of ``_CR_PIVOT_TOL``).

    ``norm="l2"``: ``|rho| <= tol ||z||_2 ||A z||_2``. ``norm="M"``:
    ``|rho| <= tol <r, z>^{1/2} <A z, M A z>^{1/2}``, the Cauchy-Schwarz bound in the
    M^{-1} / M pairing, which is invariant when the unknowns' blocks are scaled
    differently (x -> D x, r -> D^{-1} r, M -> D M D): the l2 cosine is not, so a saddle
    point system with rho -> s rho would switch recurrences at other iterations.

    The inner products of the test are taken together with ``rho`` (:meth:`KrylovSolver.inners`:
    one reduction over ranks for ``"l2"``, two for ``"M"``, whose ``M A z`` needs a finite
    ``rho`` first). A non-finite ``rho`` is returned with ``False`` (the caller's breakdown).
    """
    if st.norm == "M":
        rho = st.inner(z, az)
        if not math.isfinite(rho):
            return rho, None, False
        maz = st.precondition(az)
        rz, am = st.inners([(st.r, z), (az, maz)])
        return rho, maz, abs(rho) <= _CR_PIVOT_TOL * math.sqrt(abs(rz)) * math.sqrt(abs(am))
    rho, zz, aa = st.inners([(z, az), (z, z), (az, az)])
    if not math.isfinite(rho):
        return rho, None, False
    return rho, None, abs(rho) <= _CR_PIVOT_TOL * _norm_of(st, z, zz) * _norm_of(st, az, aa)


def _norm_of(st: PCR, v: np.ndarray, vv: float) -> float:
    """||v||_2 from ``vv = <v, v>``: its square root where that is exact to rounding (the fast path
    of :func:`~ddsolve.krylov.convergence.norm2`), else the scaled :meth:`KrylovSolver.l2norm`."""
    return math.sqrt(vv) if _DOT_MIN <= vv < math.inf else st.l2norm(v)


def _two_term(st: PCR) -> str:
    """Conjugate residual recurrences for ``M A`` in the ``M^{-1}`` inner product::

        z_0 = M r_0,  p_0 = z_0,  A p_0 = A z_0,  rho_0 = <z_0, A z_0>
        alpha_k   = rho_k / <A p_k, M A p_k>
        x_{k+1}   = x_k + alpha_k p_k
        r_{k+1}   = r_k - alpha_k A p_k
        z_{k+1}   = z_k - alpha_k M A p_k
        rho_{k+1} = <z_{k+1}, A z_{k+1}>,   beta_k = rho_{k+1} / rho_k
        p_{k+1}   = z_{k+1} + beta_k p_k
        A p_{k+1} = A z_{k+1} + beta_k A p_k,   M A p_{k+1} = M (A p_{k+1})

    (``norm="M"``: ``M A p_{k+1} = M A z_{k+1} + beta_k M A p_k``, with ``M A z``
    needed by the invariant pivot test, :func:`_cr_pivot`.) One operator
    (``A z``) and one preconditioner application per iteration. ``z`` is ``st.z``, updated in place by :meth:`PCR.step`.
    Returns ``_SWITCH`` when ``rho`` is numerically zero.
    """
    if st.z is None:
        st.z = st.precondition(st.r)
    z = st.z
    az = st.op(z)
    rho, maz, vanishes = _cr_pivot(st, z, az)
    if not math.isfinite(rho):
        st.reason = f"breakdown: non-finite <z, A z> at iteration {st.iterations + 1}"
        return BREAKDOWN
    m_geometry = st.norm == "M"
    if vanishes:
        return _SWITCH
    p = z.copy()
    ap = az
    map_ = maz if m_geometry else st.precondition(ap)
    while True:
        den = st.inner(ap, map_)
        if not (den > 0.0 and math.isfinite(den)):
            return st.breakdown_denominator(den)
        alpha = rho / den
        if not math.isfinite(alpha):
            st.reason = f"breakdown: non-finite step length at iteration {st.iterations + 1}"
            return BREAKDOWN
        outcome = st.step(alpha, p, ap, map_)     # also z -= alpha M A p
        if outcome is not None:
            return outcome
        az = st.op(z)
        rho_new, maz, vanishes = _cr_pivot(st, z, az)
        if not math.isfinite(rho_new):
            st.reason = f"breakdown: non-finite <z, A z> at iteration {st.iterations + 1}"
            return BREAKDOWN
        if vanishes:
            return _SWITCH
        beta = rho_new / rho
        rho = rho_new
        p *= beta
        p += z
        ap *= beta
        ap += az
        if m_geometry:                            # M A p = M A z + beta M A p (no extra M)
            map_ *= beta
            map_ += maz
        else:
            map_ = st.precondition(ap)


def _three_term(st: PCR) -> str:
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
    one preconditioner application per iteration. For ``norm="M"`` the
    residual's ``z = M r`` is refreshed here and then updated by
    ``z -= lambda v_{k-1}`` (``v = M A p``); for ``"l2"`` it is not carried.
    """
    tmp = st.tmp
    p = st.precondition(st.r)
    st.z = p.copy() if st.norm == "M" else None
    w = st.op(p)
    v = st.precondition(w)
    d = st.inner(w, v)
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
        lam = st.inner(st.r, v)  # <w, v> = 1 after normalisation
        if not math.isfinite(lam):
            st.reason = f"breakdown: non-finite step length at iteration {st.iterations + 1}"
            return BREAKDOWN
        outcome = st.step(lam, p, w, v)           # also z -= lambda M A p (norm="M")
        if outcome is not None:
            return outcome
        t = st.op(v)
        a0 = st.inner(t, v)
        a1 = st.inner(t, v_prev) if v_prev is not None else 0.0
        if not (math.isfinite(a0) and math.isfinite(a1)):
            st.reason = ("breakdown: non-finite orthogonalisation coefficient at "
                         f"iteration {st.iterations + 1}")
            return BREAKDOWN
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
        d = st.inner(t, v_new)
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
    norm: Literal["l2", "M"] = "l2",
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
        Stop when ``||r_k|| <= max(rtol * ||r_0||, atol)`` in the norm
        ``norm``. At least one must be > 0.
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
    norm : {"l2", "M"}
        Norm of the stopping rule, the ``residuals`` and ``true_residual``.
        ``"l2"`` (default): ``||r||_2``, which, unlike ``||r||_M``, need not
        decrease monotonically and depends on the relative scaling of the
        unknowns (e.g. the two blocks of a saddle-point system). ``"M"``:
        ``||r||_M = <r, P M r>^{1/2}``, the norm PCR minimises (monotone;
        one extra preconditioner application at the start and one for the
        true residual). Needs ``M`` symmetric positive (semi)definite on
        ``range(P)``; a clearly negative ``<r, M r>`` is a breakdown.

    Returns
    -------
    KrylovResult
        ``x`` shape (n,), ``residuals`` shape (iterations + 1,) (recursively
        updated ``||r_k||`` in the norm ``norm``), ``true_residual`` =
        ``||P (b - A x)||`` in that norm, recomputed at the end (one operator
        application, counted in ``matvecs``, and for ``norm="M"`` one
        preconditioner application). At very tight tolerances on ill-conditioned problems the
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
        ``rtol`` and ``atol`` <= 0, ``maxiter < 1``, an unusable operator, a
        ``norm`` other than ``"l2"`` and ``"M"``.
    """
    return PCR(A, b, x0, rtol=rtol, atol=atol, maxiter=maxiter, M=M, P=P, callback=callback,
               norm=norm).solve()
