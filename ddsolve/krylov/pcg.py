"""Preconditioned conjugate gradients (Figure 1.2 of Lee 2009), optionally projected.

The module also holds the argument handling shared with :mod:`ddsolve.krylov.pcr`
(operator conversion, validation, stopping rule and messages).
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import aslinearoperator

from ..errors import InputError
from .lanczos import lanczos_extreme_eigenvalues
from .result import KrylovResult

__all__ = ["pcg"]

logger = logging.getLogger(__name__)

Matvec = Callable[[np.ndarray], np.ndarray]


# --------------------------------------------------------------------------- #
# Shared helpers (also used by pcr)
# --------------------------------------------------------------------------- #
def _as_matvec(op: Any, n: int | None, name: str) -> tuple[Matvec, int]:
    """Return ``(v -> op @ v, n)`` for a square operator, checking its shape.

    ``op`` may be a dense ndarray, a scipy sparse matrix/array, a
    ``LinearOperator`` or any object with ``.matvec`` and ``.shape``. Dense and
    sparse matrices are applied with ``.dot`` directly (no LinearOperator
    overhead).
    """
    if isinstance(op, np.matrix):
        op = np.asarray(op)
    if isinstance(op, np.ndarray) or sp.issparse(op):
        shape = op.shape
        if len(shape) != 2:
            raise InputError(name, f"must be a 2-D operator, got shape {shape}")
        func: Matvec = op.dot
    else:
        try:
            lin = aslinearoperator(op)
        except (TypeError, ValueError) as exc:
            raise InputError(
                name,
                f"cannot be used as a linear operator ({type(op).__name__}): "
                "need an ndarray, sparse matrix, LinearOperator or an object "
                "with .matvec and .shape",
            ) from exc
        shape = lin.shape
        func = lin.matvec
    if shape[0] != shape[1]:
        raise InputError(name, f"must be square, got shape {tuple(shape)}")
    if n is not None and shape[0] != n:
        raise InputError(name, f"has shape {tuple(shape)}, expected ({n}, {n})")
    return func, int(shape[0])


@dataclass
class _Setup:
    """Validated arguments of a Krylov call."""

    A: Matvec
    M: Matvec | None
    P: Matvec | None
    b: np.ndarray
    x: np.ndarray
    x0_given: bool
    n: int
    rtol: float
    atol: float
    maxiter: int


def _setup(
    A: Any, b: Any, x0: Any, rtol: float, atol: float, maxiter: int | None, M: Any, P: Any
) -> _Setup:
    """Validate and convert the arguments shared by :func:`pcg` and ``pcr``."""
    if A is None:
        raise InputError("A", "operator is required")
    matvec_a, n = _as_matvec(A, None, "A")
    if n == 0:
        raise InputError("A", "operator has size 0")
    matvec_m = None if M is None else _as_matvec(M, n, "M")[0]
    matvec_p = None if P is None else _as_matvec(P, n, "P")[0]

    b_arr = np.asarray(b)
    if np.iscomplexobj(b_arr):
        raise InputError("b", "complex right-hand sides are not supported")
    b_arr = np.array(b_arr, dtype=np.float64).reshape(-1)
    if b_arr.size != n:
        raise InputError("b", f"has {b_arr.size} entries, expected {n} (operator is {n} x {n})")
    if x0 is None:
        x = np.zeros(n)
    else:
        x0_arr = np.asarray(x0)
        if np.iscomplexobj(x0_arr):
            raise InputError("x0", "complex initial guesses are not supported")
        x = np.array(x0_arr, dtype=np.float64).reshape(-1)
        if x.size != n:
            raise InputError("x0", f"has {x.size} entries, expected {n}")

    for label, value in (("rtol", rtol), ("atol", atol)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise InputError(label, f"must be a real number >= 0, got {value!r}")
        if not math.isfinite(float(value)) or float(value) < 0.0:
            raise InputError(label, f"must be a finite number >= 0, got {value!r}")
    if float(rtol) <= 0.0 and float(atol) <= 0.0:
        raise InputError("rtol", "rtol and atol are both <= 0: at least one must be positive")

    if maxiter is None:
        maxiter_int = 10 * n
    else:
        if isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer)):
            raise InputError("maxiter", f"must be an integer >= 1 or None, got {maxiter!r}")
        maxiter_int = int(maxiter)
        if maxiter_int < 1:
            raise InputError("maxiter", f"must be >= 1, got {maxiter_int}")
    return _Setup(matvec_a, matvec_m, matvec_p, b_arr, x, x0 is not None, n,
                  float(rtol), float(atol), maxiter_int)


def _apply(op: Matvec, v: np.ndarray) -> np.ndarray:
    """Apply a matvec and return a writable contiguous float64 1-D array."""
    out = op(v)
    out = np.asarray(out)
    if out.ndim != 1:
        out = out.reshape(-1)
    if out.dtype != np.float64 or not out.flags.writeable or not out.flags.c_contiguous:
        out = np.array(out, dtype=np.float64)
    return out


def _initial_residual(s: _Setup) -> tuple[np.ndarray, int]:
    """``r_0 = P (b - A x_0)`` (no operator application when ``x0`` is None)."""
    if s.x0_given:
        r = s.b - _apply(s.A, s.x)
        matvecs = 1
    else:
        r = s.b.copy()
        matvecs = 0
    if s.P is not None:
        r = _apply(s.P, r)
    return r, matvecs


def _true_residual(s: _Setup, x: np.ndarray) -> float:
    """``||P (b - A x)||_2`` recomputed from ``x`` (one operator application)."""
    r = s.b - _apply(s.A, x)
    if s.P is not None:
        r = _apply(s.P, r)
    return float(np.linalg.norm(r))


def _norm(v: np.ndarray) -> float:
    """Euclidean norm via a dot product (fast, no temporaries)."""
    return math.sqrt(float(np.dot(v, v))) if v.size else 0.0


def _readonly_view(x: np.ndarray) -> np.ndarray:
    """A read-only view of ``x`` handed to callbacks (tracks later updates)."""
    view = x.view()
    view.flags.writeable = False
    return view


def _converged_reason(rnorm: float, rnorm0: float, threshold: float) -> str:
    return f"converged: ||r||/||r0|| = {rnorm / rnorm0:.1e} <= {threshold / rnorm0:.1e}"


def _maxiter_reason(maxiter: int, rnorm: float, rnorm0: float, threshold: float) -> str:
    return (f"maxiter {maxiter} reached: ||r||/||r0|| = {rnorm / rnorm0:.1e} "
            f"> {threshold / rnorm0:.1e}")


def _initial_checks(
    s: _Setup, r: np.ndarray, matvecs: int, t0: float, rnorm0: float | None = None
) -> tuple[KrylovResult | None, float, float]:
    """Handle a zero / non-finite / already small initial residual.

    ``rnorm0`` is the norm of ``r`` in the stopping norm (``||r||_2`` when
    None). Returns ``(result, rnorm0, threshold)``; ``result`` is not None when
    the iteration must not start.
    """
    if rnorm0 is None:
        rnorm0 = _norm(r)
    if not math.isfinite(rnorm0):
        return (KrylovResult(
            x=s.x, converged=False,
            reason="breakdown: non-finite initial residual (NaN/inf in A, b, x0 or P)",
            iterations=0, residuals=np.array([rnorm0]), matvecs=matvecs,
            seconds=time.perf_counter() - t0, true_residual=None,
        ), rnorm0, 0.0)
    threshold = max(s.rtol * rnorm0, s.atol)
    if rnorm0 == 0.0 or rnorm0 <= threshold:
        reason = ("converged: ||r0|| = 0" if rnorm0 == 0.0
                  else f"converged: ||r0|| = {rnorm0:.1e} <= atol = {s.atol:.1e}")
        return (KrylovResult(
            x=s.x, converged=True, reason=reason, iterations=0,
            residuals=np.array([rnorm0]), matvecs=matvecs,
            seconds=time.perf_counter() - t0, true_residual=rnorm0,
        ), rnorm0, threshold)
    return None, rnorm0, threshold


# --------------------------------------------------------------------------- #
# PCG
# --------------------------------------------------------------------------- #
def pcg(
    A: Any,
    b: Any,
    x0: Any = None,
    *,
    rtol: float = 1e-6,
    atol: float = 0.0,
    maxiter: int | None = None,
    M: Any = None,
    P: Any = None,
    cond: bool = False,
    callback: Callable[[np.ndarray], Any] | None = None,
) -> KrylovResult:
    """Solve ``A x = b`` (``A`` SPD) by preconditioned conjugate gradients.

    Implements the PCG algorithm of Figure 1.2 of Lee (2009) (Hestenes-Stiefel
    recurrences, with the sign convention ``r = b - A x``)::

        r_0 = P (b - A x_0),  z_0 = P M r_0,  p_1 = z_0
        for k = 1, 2, ...
            q_k      = P A p_k
            alpha_k  = <z_{k-1}, r_{k-1}> / <p_k, q_k>
            x_k      = x_{k-1} + alpha_k p_k
            r_k      = r_{k-1} - alpha_k q_k
            stop if ||r_k||_2 <= max(rtol ||r_0||_2, atol)
            z_k      = P M r_k
            beta_k   = <z_k, r_k> / <z_{k-1}, r_{k-1}>
            p_{k+1}  = z_k + beta_k p_k

    With the orthogonal projection ``P`` (FETI, Section 2.5 of the thesis) this
    is the projected PCG for ``P A x = P b`` on ``x_0 + range(P)``: all
    residuals, preconditioned residuals and search directions lie in
    ``range(P)``. Without ``P`` it is plain PCG.

    Parameters
    ----------
    A : ndarray, sparse matrix, LinearOperator or object with ``.matvec``/``.shape``
        The operator, shape (n, n); symmetric positive definite (on
        ``range(P)`` when ``P`` is given).
    b : array_like, shape (n,)
        Right-hand side.
    x0 : array_like, shape (n,), optional
        Initial guess (zero by default; then no operator application is spent
        on the initial residual).
    rtol, atol : float
        Stop when ``||r_k||_2 <= max(rtol * ||r_0||_2, atol)`` (``r`` is the
        projected residual when ``P`` is given). At least one must be > 0.
    maxiter : int, optional
        Maximum number of iterations, ``10 * n`` by default.
    M : operator, shape (n, n), optional
        SPD *inverse* preconditioner applied to residuals, ``z = M r`` (as in
        scipy); identity by default.
    P : operator, shape (n, n), optional
        Orthogonal projection (symmetric, ``P^2 = P``); identity by default.
    cond : bool
        If True, record ``alpha_k`` and ``beta_k`` and return Lanczos estimates
        of the extreme eigenvalues of the preconditioned operator ``P M P A``
        (restricted to ``range(P)``) and their ratio. If False, nothing of this
        is computed and the three fields are None.
    callback : callable, optional
        ``callback(xk)`` after each iteration with a read-only view of the
        current iterate, shape (n,).

    Returns
    -------
    KrylovResult
        ``x`` has shape (n,); ``residuals`` has shape (iterations + 1,) and holds
        the recursively updated ``||r_k||_2``; ``true_residual`` is
        ``||P (b - A x)||_2`` recomputed at the end (counted in ``matvecs``).
        Non-convergence and breakdown (``<p, A p> <= 0``, a preconditioner that
        is not positive definite, NaN/inf) are reported through
        ``converged=False`` and a one-line ``reason``; ``x`` is then the last
        finite iterate.

    Raises
    ------
    InputError
        (a ``ValueError``) for invalid arguments: shape mismatch, both
        ``rtol`` and ``atol`` <= 0, ``maxiter < 1``, an unusable operator.
    """
    s = _setup(A, b, x0, rtol, atol, maxiter, M, P)
    t0 = time.perf_counter()
    x = s.x
    r, matvecs = _initial_residual(s)
    early, rnorm0, threshold = _initial_checks(s, r, matvecs, t0)
    if early is not None:
        return early

    matvec_a, apply_m, proj = s.A, s.M, s.P
    debug = logger.isEnabledFor(logging.DEBUG)
    x_view = _readonly_view(x) if callback is not None else None
    alphas: list[float] | None = [] if cond else None
    betas: list[float] | None = [] if cond else None

    def precondition(res: np.ndarray) -> np.ndarray:
        z = res.copy() if apply_m is None else _apply(apply_m, res)
        return z if proj is None else _apply(proj, z)

    residuals = [rnorm0]
    tmp = np.empty_like(x)
    z = precondition(r)
    rho = float(np.dot(r, z))
    reason = ""
    converged = False
    iterations = 0
    if not (rho > 0.0 and math.isfinite(rho)):
        reason = (f"breakdown: <r, M r> = {rho:.3e} at iteration 0 "
                  "(preconditioner not positive definite or NaN/inf)")
    else:
        p = z
        for k in range(1, s.maxiter + 1):
            q = _apply(matvec_a, p)
            matvecs += 1
            if proj is not None:
                q = _apply(proj, q)
            pq = float(np.dot(p, q))
            if not (pq > 0.0 and math.isfinite(pq)):
                reason = (f"breakdown: <p, A p> = {pq:.3e} <= 0 at iteration {k} "
                          "(operator not positive definite or NaN/inf)")
                break
            alpha = rho / pq
            if not math.isfinite(alpha):
                reason = f"breakdown: non-finite step length at iteration {k}"
                break
            np.multiply(p, alpha, out=tmp)
            x += tmp
            np.multiply(q, alpha, out=tmp)
            r -= tmp
            rnorm = _norm(r)
            residuals.append(rnorm)
            iterations = k
            if alphas is not None:
                alphas.append(alpha)
            if debug:
                logger.debug("pcg it %d: ||r||/||r0|| = %.3e", k, rnorm / rnorm0)
            if callback is not None:
                callback(x_view)
            if not math.isfinite(rnorm):
                reason = f"breakdown: non-finite residual at iteration {k}"
                break
            if rnorm <= threshold:
                converged = True
                reason = _converged_reason(rnorm, rnorm0, threshold)
                break
            if k == s.maxiter:
                reason = _maxiter_reason(s.maxiter, rnorm, rnorm0, threshold)
                break
            z = precondition(r)
            rho_new = float(np.dot(r, z))
            if not (rho_new > 0.0 and math.isfinite(rho_new)):
                reason = (f"breakdown: <r, M r> = {rho_new:.3e} at iteration {k} "
                          "(preconditioner not positive definite or NaN/inf)")
                break
            beta = rho_new / rho
            if betas is not None:
                betas.append(beta)
            p *= beta
            p += z
            rho = rho_new

    lam_min = lam_max = cond_est = None
    if alphas:
        lam_min, lam_max = lanczos_extreme_eigenvalues(alphas, betas)
        cond_est = lam_max / lam_min if lam_min > 0.0 else math.inf
    true_res = _true_residual(s, x)
    matvecs += 1
    seconds = time.perf_counter() - t0
    logger.debug("pcg: %s (%d iterations, %.3g s)", reason, iterations, seconds)
    return KrylovResult(
        x=x, converged=converged, reason=reason, iterations=iterations,
        residuals=np.asarray(residuals), lambda_min=lam_min, lambda_max=lam_max,
        cond=cond_est, matvecs=matvecs, seconds=seconds, true_residual=true_res,
    )
