"""Preconditioned conjugate gradients (Figure 1.2 of Lee 2009), optionally projected.

:class:`PCG` writes only the recurrence; the bookkeeping (arguments, history,
callback, stopping test, recomputed residual, convergence policy) is
:class:`~ddsolve.krylov.base.KrylovSolver`'s. :func:`pcg` is the scipy-style
function.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from .base import BREAKDOWN, KrylovSolver
from .lanczos import lanczos_extreme_eigenvalues
from .result import KrylovResult

__all__ = ["PCG", "pcg"]


class PCG(KrylovSolver):
    """Projected preconditioned conjugate gradients, the recurrence of :func:`pcg`.

    Parameters are those of :class:`~ddsolve.krylov.base.KrylovSolver` and
    ``cond`` (record ``alpha_k``, ``beta_k`` for Lanczos estimates).
    """

    name = "pcg"

    def __init__(self, A: Any, b: Any, x0: Any = None, *, cond: bool = False, **kwargs: Any) -> None:
        super().__init__(A, b, x0, **kwargs)
        self.alphas: list[float] | None = [] if cond else None
        self.betas: list[float] | None = [] if cond else None

    def iterate(self) -> str:
        """Figure 1.2: ``q = P A p``, ``alpha = <z, r>/<p, q>``, ``x += alpha p``,
        ``r -= alpha q``, ``z = P M r``, ``beta = <z_new, r_new>/<z, r>``, ``p = z + beta p``.
        """
        x, r, tmp = self.x, self.r, self.tmp
        alphas, betas = self.alphas, self.betas
        op, precondition, advance = self.op, self.precondition, self.advance
        z = precondition(r)
        rho = self.inner(r, z)
        if not (rho > 0.0 and math.isfinite(rho)):
            return self.breakdown(f"breakdown: <r, M r> = {rho:.3e} at iteration 0 "
                                  "(preconditioner not positive definite or NaN/inf)")
        p = z
        for k in range(1, self.maxiter + 1):
            q = op(p)
            pq = self.inner(p, q)
            if not (pq > 0.0 and math.isfinite(pq)):
                return self.breakdown(f"breakdown: <p, A p> = {pq:.3e} <= 0 at iteration {k} "
                                      "(operator not positive definite or NaN/inf)")
            alpha = rho / pq
            if not math.isfinite(alpha):
                return self.breakdown(f"breakdown: non-finite step length at iteration {k}")
            np.multiply(p, alpha, out=tmp)
            x += tmp
            np.multiply(q, alpha, out=tmp)
            r -= tmp
            if alphas is not None:
                alphas.append(alpha)
            outcome = advance(self.l2norm(r))
            if outcome is not None:
                return outcome
            z = precondition(r)
            rho_new = self.inner(r, z)
            if not (rho_new > 0.0 and math.isfinite(rho_new)):
                if self.M is not None:
                    why = "preconditioner not positive definite or NaN/inf"
                elif not math.isfinite(rho_new):
                    why = "NaN/inf: the iterates diverge, as for a singular A and b outside its range"
                else:       # <r, P r> <= 0: rounding of a vanishing residual, or a P that is not a projection
                    why = ("the residual is lost to rounding" if self.P is None else
                           "the projected residual is lost to rounding, or P is not an orthogonal projection")
                return self.breakdown(f"breakdown: <r, M r> = {rho_new:.3e} at iteration {k} ({why})")
            beta = rho_new / rho
            if betas is not None:
                betas.append(beta)
            p *= beta
            p += z
            rho = rho_new
        return BREAKDOWN  # pragma: no cover - advance() stops at maxiter

    def result_fields(self) -> dict[str, Any]:
        """Lanczos estimates of the extreme eigenvalues of ``P M P A`` (``cond=True``)."""
        if not self.alphas:
            return {}
        lam_min, lam_max = lanczos_extreme_eigenvalues(self.alphas, self.betas)
        return {"lambda_min": lam_min, "lambda_max": lam_max,
                "cond": lam_max / lam_min if lam_min > 0.0 else math.inf}


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
        ``||P (b - A x)||_2`` recomputed at the end (counted in ``matvecs``);
        ``converged`` also requires it to be finite and within
        :data:`~ddsolve.krylov.convergence.TRUE_RESIDUAL_FACTOR` of the
        threshold (``attained``). ``b = 0`` (without ``P``) gives ``x = 0``.
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
    return PCG(A, b, x0, rtol=rtol, atol=atol, maxiter=maxiter, M=M, P=P, cond=cond,
               callback=callback).solve()
