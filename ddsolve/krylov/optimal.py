"""The fewest iterations any Krylov method with a given preconditioner can need.

For ``A x = b`` with an (inverse) preconditioner ``M``, every Krylov method
that applies ``M A`` once per iteration (PCG, PCR, MINRES, GMRES, ...) has its
n-th iterate in

    x_0 + K_n(M A, M r_0),   K_n(C, v) = span{v, C v, ..., C^{n-1} v}.

The smallest residual norm reachable there,

    rho_n = min_{x in x_0 + K_n} ||b - A x||,

is therefore a lower bound for the residual of every such method after ``n``
iterations, and the first ``n`` with ``rho_n <= rtol ||r_0||`` is the fewest
iterations any of them can need for the stopping rule
``||r_n|| / ||r_0|| <= rtol`` (the rule of Section 4.4 of Lee 2009). This
module computes ``rho_n`` as a full-orthogonalisation GMRES-type minimisation:
an orthonormal basis ``V_n`` of ``K_n`` (Arnoldi on ``M A`` with two passes
of classical Gram-Schmidt, i.e. re-orthogonalisation, so the basis stays
orthonormal to rounding), and at every ``n`` the least-squares problem
``min_y ||W (r_0 - A V_n y)||_2`` solved by a QR factorisation of
``W A V_n``, with ``W = I`` (``norm="l2"``) or ``W = M^{1/2}``
(``norm="M"``, through ``||r||_M^2 = <r, M r>``; then ``M`` must be SPD).

The cost is one ``A`` and one ``M`` application per iteration plus
O(N n) storage for the basis: an analysis tool for small and moderate
problems, not a solver.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .base import as_matvec

__all__ = ["MinimalResidualCounts", "minimal_residual_counts"]


@dataclass(frozen=True)
class MinimalResidualCounts:
    """Result of :func:`minimal_residual_counts`.

    Attributes
    ----------
    iterations : int or None
        Fewest ``n`` with ``rho_n <= rtol ||r_0||``; None when not reached
        within ``maxiter`` (or when the Krylov space became invariant first).
    residuals : ndarray, shape (m + 1,)
        ``rho_0 = ||r_0||, rho_1, ..., rho_m``, the minimal residual norms.
    r0_norm : float
        ``||r_0||`` in ``norm``.
    rtol : float
    norm : str
    invariant : bool
        True when the Krylov space became invariant (a lucky breakdown): the
        minimum over it is then the minimum over every larger n.
    """

    iterations: int | None
    residuals: np.ndarray = field(repr=False)
    r0_norm: float
    rtol: float
    norm: str
    invariant: bool = False

    @property
    def relative(self) -> np.ndarray:
        """``rho_n / ||r_0||``, shape (m + 1,)."""
        return self.residuals / self.r0_norm if self.r0_norm > 0 else np.zeros_like(self.residuals)


def _matvec(op: Any, n: int, name: str) -> Any:
    """``v -> op @ v`` for an operator (see :func:`~ddsolve.krylov.base.as_matvec`) or a plain callable."""
    if callable(op) and not hasattr(op, "shape"):
        return op
    return as_matvec(op, n, name)[0]


def _apply(Mmv: Any, v: np.ndarray) -> np.ndarray:
    return np.asarray(Mmv(v), dtype=np.float64).ravel()


def minimal_residual_counts(A: Any, b: Any, M: Any = None, x0: Any = None, *, rtol: float = 1e-6,
                            maxiter: int = 200, norm: Literal["l2", "M"] = "l2",
                            reorthogonalize: bool = True) -> MinimalResidualCounts:
    """Fewest iterations any Krylov method with preconditioner ``M`` needs for ``A x = b``.

    Minimises ``||b - A x||`` over ``x in x_0 + K_n(M A, M r_0)`` for
    ``n = 1, 2, ...`` (see the module docstring) and returns the first ``n``
    with ``min ||r_n|| <= rtol ||r_0||``.

    Parameters
    ----------
    A : matrix, LinearOperator or callable, shape (N, N)
        Any square operator (it need not be symmetric).
    b : array_like, shape (N,)
    M : matrix, LinearOperator or callable, shape (N, N), optional
        Inverse preconditioner (default identity: unpreconditioned GMRES).
    x0 : array_like, shape (N,), optional
        Initial guess (default zero).
    rtol : float
        Relative tolerance of the stopping rule ``||r_n|| <= rtol ||r_0||``.
    maxiter : int
        Largest ``n`` examined (the basis holds ``maxiter + 1`` vectors).
    norm : {"l2", "M"}
        ``||r||_2`` or ``||r||_M = <r, M r>^{1/2}`` (``M`` SPD), the two
        stopping norms of :func:`ddsolve.krylov.pcr`.
    reorthogonalize : bool
        Second Gram-Schmidt pass (default True; keep it: without it the basis
        loses orthogonality and ``rho_n`` is no longer the exact minimum).

    Returns
    -------
    MinimalResidualCounts
    """
    if norm not in ("l2", "M"):
        raise ValueError(f"norm must be 'l2' or 'M', got {norm!r}")
    if not (rtol > 0 and math.isfinite(rtol)):
        raise ValueError(f"rtol must be positive and finite, got {rtol!r}")
    b = np.asarray(b, dtype=np.float64).ravel()
    N = b.size
    Amv = _matvec(A, N, "A")
    Mmv = _matvec(M, N, "M") if M is not None else (lambda v: v)
    if norm == "M" and M is None:
        norm = "l2"
    x0 = np.zeros(N) if x0 is None else np.asarray(x0, dtype=np.float64).ravel()
    r0 = b - np.asarray(Amv(x0), dtype=np.float64).ravel() if np.any(x0) else b.copy()

    z0 = _apply(Mmv, r0)
    if norm == "M":
        r0n = math.sqrt(max(float(np.dot(r0, z0)), 0.0))
    else:
        r0n = float(np.linalg.norm(r0))
    residuals = [r0n]
    if r0n == 0.0:
        return MinimalResidualCounts(0, np.array(residuals), r0n, rtol, norm)

    V = np.zeros((N, maxiter + 1))
    AV = np.zeros((N, maxiter))           # A v_j
    MAV = np.zeros((N, maxiter))          # M A v_j (for the M-norm Gram matrix)
    beta = float(np.linalg.norm(z0))
    if beta == 0.0:
        return MinimalResidualCounts(None, np.array(residuals), r0n, rtol, norm, invariant=True)
    V[:, 0] = z0 / beta
    target = rtol * r0n
    iterations: int | None = None
    invariant = False
    for n in range(1, maxiter + 1):
        j = n - 1
        av = np.asarray(Amv(V[:, j]), dtype=np.float64).ravel()
        w = _apply(Mmv, av)
        AV[:, j] = av
        MAV[:, j] = w
        # Arnoldi step on C = M A with (re-)orthogonalisation
        passes = 2 if reorthogonalize else 1
        wnorm0 = float(np.linalg.norm(w))
        for _ in range(passes):
            w = w - V[:, :n] @ (V[:, :n].T @ w)
        h = float(np.linalg.norm(w))
        rho = _least_squares_residual(AV[:, :n], MAV[:, :n], r0, z0, norm)
        residuals.append(rho)
        if iterations is None and rho <= target:
            iterations = n
            break
        if h <= 1e-14 * max(wnorm0, 1.0) or n == maxiter:
            invariant = h <= 1e-14 * max(wnorm0, 1.0)
            break
        V[:, n] = w / h
    return MinimalResidualCounts(iterations, np.array(residuals), r0n, rtol, norm, invariant=invariant)


def _least_squares_residual(AV: np.ndarray, MAV: np.ndarray, r0: np.ndarray, z0: np.ndarray,
                            norm: str) -> float:
    """``min_y ||r0 - AV y||`` in the l2 norm or in ``<r, M r>^{1/2}``.

    l2: QR of ``AV`` (orthogonal, so the projection of ``r0`` onto range(AV)
    is exact to rounding). M-norm: the normal equations in the ``M`` inner
    product ``G y = c`` with ``G = AV^T M AV`` (symmetrised), ``c = AV^T M r0``,
    solved by an eigendecomposition of ``G`` (pseudo-inverse of its numerical
    range), and ``rho^2 = <r0, M r0> - c^T y``.
    """
    if norm == "l2":
        Q, R = np.linalg.qr(AV)
        # drop numerically dependent columns (rank-revealing through R's diagonal)
        d = np.abs(np.diag(R))
        keep = d > 1e-13 * max(float(d.max()) if d.size else 0.0, 1e-300)
        Qk = Q[:, keep]
        res = r0 - Qk @ (Qk.T @ r0)
        res = res - Qk @ (Qk.T @ res)      # second projection pass
        return float(np.linalg.norm(res))
    G = AV.T @ MAV
    G = 0.5 * (G + G.T)
    c = MAV.T @ r0
    evals, evecs = np.linalg.eigh(G)
    keep = evals > 1e-13 * max(float(evals.max()), 1e-300)
    cc = evecs[:, keep].T @ c
    rr = float(np.dot(r0, z0)) - float(np.sum(cc * cc / evals[keep]))
    return math.sqrt(max(rr, 0.0))
