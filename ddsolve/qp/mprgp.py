"""MPRGP: Modified Proportioning with Reduced Gradient Projections.

Solves the bound constrained convex quadratic program (6.6) of Lee's thesis,

.. math::

    \\min_{x \\ge l} f(x) = \\tfrac12 x^T A x - b^T x ,

with the algorithm of Figure 6.6 (Section 6.2), due to Dostál [13], [14, Chapter 5].
Entries of ``l`` may be ``-inf`` (free variables).

Notation (Section 6.2, (6.9)): with ``g = A x - b``, the free set
``F(x) = {i : x_i > l_i}`` and the active set ``A(x) = {i : x_i = l_i}``,

* free gradient ``phi_i = g_i`` on ``F``, 0 on ``A``;
* chopped gradient ``beta_i = min(g_i, 0)`` on ``A``, 0 on ``F``;
* projected gradient ``g^P = phi + beta``; ``g^P(x) = 0`` is the KKT condition (6.7)-(6.8);
* reduced free gradient ``phit_i = min((x_i - l_i) / alpha, phi_i)`` on ``F``, 0 on ``A``
  ([14, Section 5.8]).

Each iteration is one of three steps (Figure 6.6):

* the iterate is *proportional*, ``||beta||^2 <= Gamma^2 phit^T phi`` (the precise form of
  "phi(x^k) dominates" in Figure 6.6, taken from [14, Section 5.8]):

  - **CG step** if the conjugate gradient step ``y = x - alpha_cg p`` is feasible
    (``alpha_cg <= alpha_f``);
  - **expansion step** otherwise: ``x <- P(x - alpha phi(x))`` with the fixed steplength
    ``alpha`` in ``(0, 2/||A||]``, then ``g = A x - b`` is recomputed and the CG
    direction is restarted, ``p = phi(x)``. By default the expansion is preceded by the
    feasible half step ``x <- x - alpha_f p`` to the boundary (Dostál's MPRGP,
    [14, Section 5.8]; it needs no extra multiplication by ``A`` and guarantees
    monotone decrease of ``f``); ``halfstep=False`` gives Figure 6.6 literally;

* otherwise a **proportioning step** along the chopped gradient,
  ``x <- x - alpha_cg beta``, ``alpha_cg = g^T beta / beta^T A beta`` (exact line search;
  it releases variables from their bounds), and ``p = phi(x)``.

Cost: one multiplication by ``A`` per CG or proportioning step, two per expansion step.

Scale invariance: :func:`mprgp` solves the problem rescaled by powers of two
(:mod:`ddsolve.qp.scaling`: ``||A'||`` and ``||b'||`` in ``[1, 2)``), which is exact in
binary floating point: the iterates are the same numbers as those of the unscaled
iteration (bit-identical results) wherever that one does not over- or underflow, and
the curvatures ``p^T A p`` stay representable for ``A`` and ``b`` anywhere in the
double range (e.g. multipliers of size 1e150 or 1e-150).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, aslinearoperator

from ..errors import InputError
from ..krylov.convergence import TRUE_RESIDUAL_FACTOR, norm2
from .norm import estimate_norm
from .result import QPResult
from .scaling import QPScaling

log = logging.getLogger(__name__)

#: Default expansion steplength factor: ``alpha = ALPHA_FACTOR / ||A||`` (in (0, 2/||A||]).
ALPHA_FACTOR = 1.9

#: A converged MPRGP run is accepted only if the projected gradient recomputed as A x - b at its last
#: iterate meets the rule within this factor (the recursively updated one drifts; the same factor as
#: :data:`ddsolve.krylov.convergence.TRUE_RESIDUAL_FACTOR` of PCG's true residual).
TRUE_GRADIENT_FACTOR = TRUE_RESIDUAL_FACTOR
#: How often the iteration goes on from the recomputed gradient before it reports the tolerance unattainable.
MAX_REPLACEMENTS = 3

#: ``stop(x, gp_norm)`` returns a one-line message when the iteration should stop
#: (converged), ``None`` otherwise.
StopRule = Callable[[np.ndarray, float], "str | None"]


# --------------------------------------------------------------------------- helpers
def as_operator(A: Any, shape: tuple[int, int] | None, name: str) -> LinearOperator:
    """Wrap ``A`` as a :class:`~scipy.sparse.linalg.LinearOperator` and check its shape.

    Parameters
    ----------
    A : ndarray, sparse matrix or LinearOperator
        Anything :func:`scipy.sparse.linalg.aslinearoperator` accepts.
    shape : tuple of int or None
        Required shape; ``-1`` in an entry means "any"; ``None`` means no check.
    name : str
        Argument name used in error messages.

    Raises
    ------
    ValueError
        (:class:`~ddsolve.errors.InputError`) if ``A`` is not an operator or has the wrong shape.
    """
    try:
        op = aslinearoperator(A)
    except (TypeError, ValueError) as exc:
        raise InputError(name, f"must be an ndarray, sparse matrix or LinearOperator ({exc})") from None
    if np.issubdtype(np.dtype(op.dtype), np.complexfloating):
        raise InputError(name, "complex operators are not supported")
    if shape is not None:
        for got, want in zip(op.shape, shape):
            if want >= 0 and got != want:
                raise InputError(name, f"has shape {op.shape}, expected {shape}".replace("-1", "m"))
    entries = A.data if sp.issparse(A) else A if isinstance(A, np.ndarray) else None
    if entries is not None and np.issubdtype(entries.dtype, np.number) and not np.all(np.isfinite(entries)):
        # a NaN reached ARPACK/LAPACK in the norm estimate: "Eigenvalues did not converge" (a review)
        raise InputError(name, "has non-finite entries (NaN or Inf)")
    return op


def as_vector(v: Any, n: int, name: str, *, allow_scalar: bool = False,
              allow_neg_inf: bool = False) -> np.ndarray:
    """Return ``v`` as a float64 vector of shape ``(n,)`` (a fresh copy).

    Parameters
    ----------
    v : array_like
        Input vector (or scalar if ``allow_scalar``, broadcast to ``(n,)``).
    n : int
        Required length.
    name : str
        Argument name used in error messages.
    allow_scalar : bool
        Accept a scalar and broadcast it.
    allow_neg_inf : bool
        Accept ``-inf`` entries (lower bounds); NaN and ``+inf`` are always rejected.
    """
    if np.iscomplexobj(v):
        raise InputError(name, "complex values are not supported")
    try:
        arr = np.array(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(name, f"must be a real vector of length {n}") from None
    if arr.ndim == 0 and allow_scalar:
        arr = np.full(n, float(arr))
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.ravel()
    if arr.shape != (n,):
        raise InputError(name, f"has shape {arr.shape}, expected ({n},)")
    if allow_neg_inf:
        if np.isnan(arr).any() or (arr == np.inf).any():
            raise InputError(name, "must not contain NaN or +inf")
    elif not np.isfinite(arr).all():
        raise InputError(name, "must be finite (no NaN or inf)")
    return arr


def check_positive(name: str, value: Any, *, strict: bool = True) -> float:
    """Return ``float(value)``; raise :class:`~ddsolve.errors.InputError` unless finite and > 0 (>= 0)."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(name, f"must be a number, got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(out) or (out <= 0 if strict else out < 0):
        raise InputError(name, f"must be a finite number {'>' if strict else '>='} 0, got {value!r}")
    return out


def checked_norm(op: Any, name: str) -> tuple[float, int]:
    """:func:`~ddsolve.qp.norm.estimate_norm` of a caller's operator, an :class:`InputError` naming it where
    its products are not finite."""
    try:
        return estimate_norm(op)
    except FloatingPointError as exc:
        raise InputError(name, str(exc)) from None


def check_count(name: str, value: Any, minimum: int = 0) -> int:
    """Return ``int(value)``; raise :class:`~ddsolve.errors.InputError` unless an integer >= minimum."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InputError(name, f"must be an integer >= {minimum}, got {value!r}")
    return int(value)


# --------------------------------------------------------------------------- core
class _NonFinite(Exception):
    """A product with A returned NaN or Inf (inside :func:`_mprgp_core`)."""


@dataclass
class _CoreResult:
    x: np.ndarray
    g: np.ndarray
    converged: bool
    reason: str
    steps: int = 0
    n_matvec: int = 0
    n_cg: int = 0
    n_expansion: int = 0
    n_proportioning: int = 0
    gp_norms: list[float] = field(default_factory=list)


def _split_squares(x: np.ndarray, lb: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(phi, beta, ||phi||^2, ||beta||^2) of the gradient splitting (6.9) at ``x``."""
    free = x > lb
    phi = np.where(free, g, 0.0)
    beta = np.where(free, 0.0, np.minimum(g, 0.0))
    return phi, beta, float(phi @ phi), float(beta @ beta)


def gradient_norm(phi: np.ndarray, beta: np.ndarray, phi2: float, beta2: float) -> float:
    """``||g^P|| = sqrt(||phi||^2 + ||beta||^2)`` from the squares, safe against over/underflow.

    The squares are used when their sum is finite and not tiny (the same number as before);
    otherwise the scaled norms (:func:`~ddsolve.krylov.convergence.norm2`) are combined by ``hypot``.
    """
    total = phi2 + beta2
    if 2.0 ** -880 <= total < math.inf:
        return math.sqrt(total)
    return math.hypot(norm2(phi), norm2(beta))


def _mprgp_core(matvec: Callable[[np.ndarray], np.ndarray], b: np.ndarray, lb: np.ndarray,
                x: np.ndarray, g: np.ndarray, *, alpha: float, Gamma: float, stop: StopRule,
                maxiter: int, halfstep: bool = True, g_exp: int = 0,
                confirm: Callable[[str], bool] | None = None) -> _CoreResult:
    """Run the MPRGP iteration of Figure 6.6 from a feasible ``x`` with ``g = A x - b``.

    Parameters
    ----------
    matvec : callable
        ``v -> A v`` for ``v`` of shape (n,).
    b, lb : ndarray, shape (n,)
        Right-hand side and lower bounds (``-inf`` allowed).
    x, g : ndarray, shape (n,)
        Feasible start (``x >= lb``) and its gradient ``A x - b``; not modified.
    alpha : float
        Fixed expansion steplength in ``(0, 2/||A||]``.
    Gamma : float
        Proportioning parameter (> 0).
    stop : callable
        Stopping rule ``stop(x, ||g^P(x)||) -> str | None``, evaluated before every step.
    maxiter : int
        Maximum number of steps.
    halfstep : bool
        Precede each expansion step by the feasible half step (see module docstring).
    g_exp : int
        The gradients are ``2^g_exp`` times those of the caller's units (rescaled problem,
        :mod:`ddsolve.qp.scaling`): used for the norms quoted in messages only.
    confirm : callable, optional
        ``confirm(message) -> bool``: whether a stop of ``stop`` is confirmed with the recomputed
        gradient (default: every stop). SMALBE confirms only the stop that ends it, not the
        loose inner stops after which its next outer iteration goes on from ``g`` anyway (that
        cost one more product per outer iteration, 8-12% more, a review).
    """
    debug = log.isEnabledFor(logging.DEBUG)
    user_matvec = matvec

    def matvec(v: np.ndarray) -> np.ndarray:         # noqa: F811  (the caller's, checked)
        out_v = user_matvec(v)
        if not np.all(np.isfinite(out_v)):
            raise _NonFinite
        return out_v

    x = x.copy()
    g = g.copy()
    out = _CoreResult(x=x, g=g, converged=False, reason="")
    Gamma2 = Gamma * Gamma
    p = np.where(x > lb, g, 0.0)                     # p = phi(x^0)
    fresh = True                                     # g is A x - b as computed, not updated recursively
    replacements, last_true = 0, math.inf
    try:
        while True:
            # gradient splitting (6.9)
            free = x > lb
            phi, beta, phi2, beta2 = _split_squares(x, lb, g)
            gp_norm = gradient_norm(phi, beta, phi2, beta2)
            out.gp_norms.append(gp_norm)
            msg = stop(x, gp_norm)
            if msg is not None and not fresh and (confirm is None or confirm(msg)):
                # the recursively updated g drifts from A x - b (a review: cond 1e10, rtol 1e-9, the recomputed
                # ||g^P|| 100-1e6 times the threshold, reported converged): accept only what the recomputed
                # gradient confirms within TRUE_GRADIENT_FACTOR, else go on from it (residual replacement)
                g = matvec(x) - b
                out.n_matvec += 1
                fresh = True
                true_norm = gradient_norm(*_split_squares(x, lb, g))
                if stop(x, true_norm / TRUE_GRADIENT_FACTOR) is None:
                    replacements += 1
                    # give up after MAX_REPLACEMENTS, or at once when going on did not lower it (rounding)
                    if (replacements > MAX_REPLACEMENTS or not math.isfinite(true_norm)
                            or true_norm >= last_true):
                        out.reason = (f"tolerance not attained: the recomputed ||g^P|| = "
                                      f"{QPScaling.up(true_norm, g_exp):.3e} stays above {TRUE_GRADIENT_FACTOR:g} x "
                                      f"the threshold that the recursively updated one met ({msg}); "
                                      f"{replacements} recomputation(s) (a tolerance below the attainable accuracy)")
                        break
                    last_true = true_norm
                    p = np.where(x > lb, g, 0.0)
                    out.gp_norms.pop()                   # the same x^k: its norm is the recomputed one, appended next
                    continue
            if msg is not None:
                out.converged, out.reason = True, msg
                break
            if out.steps >= maxiter:
                out.reason = f"maxiter {maxiter} reached: ||g^P|| = {QPScaling.up(gp_norm, g_exp):.3e}"
                break

            # proportioning test ||beta||^2 <= Gamma^2 phit^T phi  ([14, Section 5.8])
            if beta2 > 0.0:
                with np.errstate(invalid="ignore"):
                    phit = np.where(free, np.minimum((x - lb) / alpha, phi), 0.0)
                proportional = beta2 <= Gamma2 * float(phit @ phi)
            else:
                proportional = True

            if proportional:
                g_p = float(g @ p)
                if g_p <= 0.0:                           # safeguard (round-off): restart with p = phi
                    p = phi.copy()
                    g_p = phi2
                Ap = matvec(p)
                out.n_matvec += 1
                pAp = float(p @ Ap)
                a_cg = g_p / pAp if pAp > 0.0 else math.inf
                # feasible steplength alpha_f = min{(x_i - l_i) / p_i : p_i > 0} and its index
                pos = np.flatnonzero(p > 0.0)
                a_f, block = math.inf, -1
                if pos.size:
                    ratios = (x[pos] - lb[pos]) / p[pos]
                    j = int(np.argmin(ratios))
                    a_f, block = float(ratios[j]), int(pos[j])
                if math.isinf(a_cg) and math.isinf(a_f):
                    out.reason = ("breakdown: p^T A p <= 0 along an unbounded feasible direction "
                                  "(problem unbounded below or A not positive definite)")
                    break
                if a_cg <= a_f:
                    # conjugate gradient step
                    x -= a_cg * p
                    np.maximum(x, lb, out=x)             # round-off only: y is feasible
                    g -= a_cg * Ap
                    fresh = False
                    phi_y = np.where(x > lb, g, 0.0)
                    p = phi_y - (float(phi_y @ Ap) / pAp) * p
                    out.n_cg += 1
                    kind = "cg"
                else:
                    # expansion step
                    if halfstep:
                        x -= a_f * p                     # feasible half step to the boundary
                        np.maximum(x, lb, out=x)
                        x[block] = lb[block]             # the blocking bound becomes active exactly
                        g -= a_f * Ap
                        phi = np.where(x > lb, g, 0.0)
                    x -= alpha * phi
                    np.maximum(x, lb, out=x)             # projection P onto Omega_B
                    g = matvec(x) - b
                    out.n_matvec += 1
                    fresh = True
                    p = np.where(x > lb, g, 0.0)
                    out.n_expansion += 1
                    kind = "expansion"
            else:
                # proportioning step along the chopped gradient
                d = beta
                Ad = matvec(d)
                out.n_matvec += 1
                dAd = float(d @ Ad)
                if dAd <= 0.0:
                    out.reason = ("breakdown: beta^T A beta <= 0 along an unbounded feasible direction "
                                  "(problem unbounded below or A not positive definite)")
                    break
                a_cg = beta2 / dAd                       # g^T beta = ||beta||^2
                x -= a_cg * d
                g -= a_cg * Ad
                fresh = False
                p = np.where(x > lb, g, 0.0)
                out.n_proportioning += 1
                kind = "proportioning"
            out.steps += 1
            if debug:
                log.debug("MPRGP step %d (%s): ||g^P|| = %.3e before the step", out.steps, kind,
                          QPScaling.up(gp_norm, g_exp))
    except _NonFinite:
        # x is the last iterate computed from finite products (feasible); g may be stale
        out.converged = False
        out.reason = ("breakdown: A returned non-finite values (NaN or Inf) after "
                      f"{out.steps} steps")
    out.x, out.g = x, g
    return out


# --------------------------------------------------------------------------- public API
def mprgp(A: Any, b: Any, lb: Any, x0: Any = None, *, Gamma: float = 1.0, alpha: float | None = None,
          norm_A: float | None = None, rtol: float = 1e-5, atol: float = 0.0,
          maxiter: int | None = None, tol: float | StopRule | None = None,
          halfstep: bool = True) -> QPResult:
    """Solve ``min 1/2 x^T A x - b^T x  s.t.  x >= lb`` by MPRGP (Figure 6.6).

    See the module docstring for the algorithm.

    Parameters
    ----------
    A : ndarray, sparse matrix or LinearOperator, shape (n, n)
        Symmetric positive semidefinite Hessian, positive definite on the directions the
        iteration explores (e.g. the penalised projected Hessian ``P F P + rho Q`` of (6.17)).
    b : array_like, shape (n,)
        Linear term.
    lb : array_like, shape (n,) or scalar
        Lower bounds; ``-inf`` entries are free variables.
    x0 : array_like, shape (n,), optional
        Start vector (default ``max(0, lb)``); an infeasible ``x0`` is projected onto
        ``{x >= lb}``.
    Gamma : float
        Proportioning parameter ``Gamma > 0`` (Section 6.4 uses ``Gamma = 1``).
    alpha : float, optional
        Fixed expansion steplength in ``(0, 2/||A||]`` (Figure 6.6). Default
        ``1.9 / ||A||`` (Section 6.4 does not state a value).
    norm_A : float, optional
        ``||A||_2``; estimated by seeded Lanczos (:func:`~ddsolve.qp.norm.estimate_norm`, whose
        multiplications are counted in ``n_hessian``) when not given.
    rtol, atol : float
        Stopping rule ``||g^P(x)|| <= max(rtol * ||b||, atol)``: the relative rule
        ``||g^P|| <= eps ||b||`` of Section 6.4 with ``eps = rtol`` (Figure 6.6 iterates
        while ``g^P(x^k) > 0``); ``atol`` guards ``b = 0``.
    maxiter : int, optional
        Maximum number of MPRGP steps (default ``max(100, 10 n)``). Reaching it returns
        ``converged=False``; nothing is raised.
    tol : float or callable, optional
        Overrides ``rtol``/``atol``: a float is an absolute tolerance on ``||g^P||``; a
        callable ``tol(x, gp_norm) -> str | None`` is an arbitrary stopping rule (return a
        message to stop), e.g. the adaptive inner rule of SMALBE (Figure 6.7).

        A stop met by the recursively updated gradient is confirmed with g = A x - b
        recomputed (one more product with A): the rule is called once more with a tenth
        (1 / ``TRUE_GRADIENT_FACTOR``) of that ||g^P||. If it refuses, the iteration goes on
        from the recomputed gradient; when a recomputation no longer lowers the recomputed
        ||g^P||, or after ``MAX_REPLACEMENTS`` + 1 refusals, it ends with ``converged=False``,
        "tolerance not attained" (a tolerance below the attainable accuracy; as PCG's
        true-residual check).
    halfstep : bool
        Precede each expansion step by the feasible half step ``x - alpha_f p`` (Dostál,
        [14, Section 5.8]; default). ``False`` follows Figure 6.6 literally.

    Returns
    -------
    QPResult
        ``x``, ``converged``, ``reason``, ``iterations`` (steps), step counters,
        ``n_hessian``, ``gradient_norms`` (``||g^P(x^k)||``, k = 0..iterations), ``alpha``.

    Raises
    ------
    ValueError
        (:class:`~ddsolve.errors.InputError`) on shape mismatch, non-finite data,
        ``Gamma <= 0``, ``alpha`` outside ``(0, 2/||A||]`` or other invalid arguments.
    """
    t0 = time.perf_counter()
    n = int(np.asarray(b).size)
    if n == 0:
        raise InputError("b", "must be a non-empty vector")
    b = as_vector(b, n, "b")
    op = as_operator(A, (n, n), "A")
    lb = as_vector(lb, n, "lb", allow_scalar=True, allow_neg_inf=True)
    Gamma = check_positive("Gamma", Gamma)
    rtol = check_positive("rtol", rtol, strict=False)
    atol = check_positive("atol", atol, strict=False)
    if tol is None and rtol == 0.0 and atol == 0.0:    # as pcg: a zero threshold is met by no rounded gradient
        raise InputError("rtol", "rtol and atol are both 0: at least one must be positive")
    if tol is not None and not callable(tol) and check_positive("tol", tol, strict=False) == 0.0:
        raise InputError("tol", "must be positive: a zero threshold is met by no rounded gradient")
    maxiter = max(100, 10 * n) if maxiter is None else check_count("maxiter", maxiter)
    x = _start_vector(x0, lb, n)

    n_hessian = 0
    if norm_A is None:
        norm_A, k = checked_norm(op, "A")
        n_hessian += k
        if norm_A == 0.0:
            raise InputError("A", "is the zero operator")
    else:
        norm_A = check_positive("norm_A", norm_A)
    if alpha is None:
        alpha = ALPHA_FACTOR / norm_A
    else:
        alpha = check_positive("alpha", alpha)
        if alpha > 2.0 / norm_A * (1.0 + 1e-12):
            raise InputError("alpha", f"must lie in (0, 2/||A||] = (0, {2.0 / norm_A:.6g}], got {alpha!r}")

    # the problem in the units of :mod:`ddsolve.qp.scaling` (exact powers of two)
    sc = QPScaling.of(norm_A, b, x, lb)
    up = QPScaling.up
    stop = _make_stop(tol, rtol, atol, b, sc)

    def matvec(v: np.ndarray) -> np.ndarray:
        """A' v = 2^-a A v."""
        out = np.asarray(op.matvec(v), dtype=np.float64).ravel()
        return up(out, -sc.a) if sc.a else out

    b_s, lb_s, x_s = up(b, -sc.e), up(lb, -sc.x), up(x, -sc.x)
    g_s = matvec(x_s) - b_s
    n_hessian += 1
    if not np.all(np.isfinite(g_s)):
        return QPResult(x=x, converged=False, reason="breakdown: A returned non-finite values (NaN or Inf) "
                        "at the initial gradient", iterations=0, n_hessian=n_hessian,
                        gradient_norms=np.zeros(0), seconds=time.perf_counter() - t0, alpha=alpha)
    if tol is None and atol == 0.0 and not np.any(b):
        # the rule max(rtol ||b||, atol) is 0: met by a start whose projected gradient is exactly 0 (x0 = 0 with
        # lb <= 0: the active set method's projection at a zero load), by no rounded iterate otherwise (a review:
        # the exact answer read as a breakdown); smalbe refuses b = 0 without atol as well
        free = x_s > lb_s
        if np.any(np.where(free, g_s, np.minimum(g_s, 0.0))):
            raise InputError("atol", "b = 0 makes the stopping rule max(rtol ||b||, atol) zero, which no "
                                     "rounded iterate meets: give atol > 0")
    core = _mprgp_core(matvec, b_s, lb_s, x_s, g_s, alpha=up(alpha, sc.a), Gamma=Gamma, stop=stop,
                       maxiter=maxiter, halfstep=halfstep, g_exp=sc.e)
    x = up(core.x, sc.x)
    np.maximum(x, lb, out=x)                         # exact unless a bound was subnormal in scaled units
    res = QPResult(
        x=x, converged=core.converged, reason=core.reason, iterations=core.steps,
        n_hessian=n_hessian + core.n_matvec, n_cg=core.n_cg, n_expansion=core.n_expansion,
        n_proportioning=core.n_proportioning, gradient_norms=up(np.asarray(core.gp_norms), sc.e),
        seconds=time.perf_counter() - t0, alpha=alpha,
    )
    log.info("MPRGP n=%d: %s after %d steps (cg %d, expansion %d, proportioning %d, A-mults %d)",
             n, res.reason, res.iterations, res.n_cg, res.n_expansion, res.n_proportioning, res.n_hessian)
    return res


def _make_stop(tol: float | StopRule | None, rtol: float, atol: float, b: np.ndarray,
               sc: QPScaling = QPScaling()) -> StopRule:
    """The stopping rule ``||g^P|| <= threshold`` (or a callable ``tol``) in the scaled units ``sc``.

    The rule gets the scaled iterate ``x'`` and ``||g'^P||``; a callable ``tol`` is called with
    ``x = 2^(e-a) x'`` and ``||g^P|| = 2^e ||g'^P||`` (the caller's units), messages quote those.
    """
    up = QPScaling.up
    if callable(tol):
        user = tol
        if sc.a == 0 and sc.e == 0:
            return user
        return lambda x, gp_norm: user(up(x, sc.x), up(gp_norm, sc.e))
    if tol is not None:
        threshold = up(check_positive("tol", tol, strict=False), -sc.e)
    else:
        threshold = max(rtol * norm2(up(b, -sc.e)), up(atol, -sc.e))

    def stop(x: np.ndarray, gp_norm: float) -> str | None:
        if gp_norm <= threshold:
            return f"converged: ||g^P|| = {up(gp_norm, sc.e):.3e} <= {up(threshold, sc.e):.3e}"
        return None

    return stop


def _start_vector(x0: Any, lb: np.ndarray, n: int) -> np.ndarray:
    """Feasible start: ``x0`` projected onto ``{x >= lb}`` (default ``max(0, lb)``)."""
    if x0 is None:
        return np.maximum(0.0, lb)
    x = as_vector(x0, n, "x0")
    if (x < lb).any():
        log.debug("x0 infeasible in %d entries: projected onto the bounds", int((x < lb).sum()))
        np.maximum(x, lb, out=x)
    return x
