"""Projected PCG for FETI-type dual problems (Section 2.5, (2.13)-(2.14)).

Shared by one-level FETI and FETI-FETI: given F, d, the Dirichlet
preconditioner M and the natural coarse space G = B R, e = R^T f, solve

    P^T F lambda = P^T d,   G^T lambda = e,

with the Q-weighted projection P = I - Q G (G^T Q G)^{-1} G^T, Q diagonal
(Q = I is the orthogonal projection of the thesis). It is run as the
orthogonal projection (:class:`~ddsolve.dd.projection.Projection`) of the
similar system in mu = Q^{-1/2} lambda. Without a kernel (no floating
subdomains or bodies), P and lambda_0 are skipped.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

from ..errors import InputError
from ..krylov import KrylovResult, pcg
from .operators import linear_operator, scaled_jump
from .projection import Projection

Matvec = Callable[[np.ndarray], np.ndarray]

#: Projections of one-level FETI and FETI-FETI: ``"weighted"`` (default) Q = diag(B_D diag(rho) B_D^T)
#: under rho-scaling (Q = I under multiplicity scaling); ``"orthogonal"`` Q = I always, P of (2.13).
DUAL_PROJECTIONS: tuple[str, ...] = ("weighted", "orthogonal")


def projection_weights(B_D: sp.spmatrix, rho_W: np.ndarray, scaling: str, projection: str = "weighted"
                       ) -> np.ndarray | None:
    """Diagonal of Q of the projection (None: Q = I, the orthogonal P of (2.13)).

    Parameters
    ----------
    B_D : sparse matrix, shape (n_lambda, n_W)
        Scaled jump operator.
    rho_W : ndarray, shape (n_W,)
        Coefficient of the subdomain of every W entry.
    scaling : str
        ``"rho"`` or ``"multiplicity"`` (the latter always gives Q = I).
    projection : {"weighted", "orthogonal"}

    Returns
    -------
    ndarray, shape (n_lambda,), or None
        q = (B_D .* B_D) rho_W (for gamma = 1: rho_i rho_j / (rho_i + rho_j) on the
        multiplier between subdomains i and j), or None.
    """
    if projection not in DUAL_PROJECTIONS:
        raise InputError("projection", f"unknown projection {projection!r} (choose from {', '.join(DUAL_PROJECTIONS)})")
    if projection == "orthogonal" or scaling == "multiplicity":
        return None
    return floored_weights(B_D.multiply(B_D) @ rho_W)


def floored_weights(q: np.ndarray) -> np.ndarray | None:
    """The diagonal q of Q with its entries that underflowed to 0 raised to the smallest positive one (None,
    Q = I, when all did); the others are left as they are. Every global q goes through here, serial and
    distributed (:mod:`ddsolve.parallel.feti`, :mod:`ddsolve.parallel.fetifeti` form it on rank 0).

    Squares of tiny delta-dagger weights (large gamma; cross points of soft subdomains among stiff ones at
    contrasts beyond ~1e154) underflow to q = 0, and the scaled dual problem divides by sqrt(q): 'breakdown:
    <r, M r> = nan at iteration 0' (a review). Any positive diagonal Q gives a valid projection.
    """
    small = ~(q > 0.0)
    if not small.any():
        return q
    if small.all():
        return None
    return np.where(small, q[~small].min(), q)


def dual_operators(B: sp.spmatrix, B_D: sp.spmatrix, primal_solve: Matvec,
                   schur: Matvec) -> tuple[Matvec, Matvec]:
    """F = B K^{-1} B^T and the Dirichlet preconditioner M^{-1} = B_D S B_D^T.

    Parameters
    ----------
    B, B_D : sparse matrix, shape (n_lambda, n_W)
        Jump operator and its scaled version.
    primal_solve : callable
        W vector -> K^{-1} w (A^+ for FETI, A~^{-1} for FETI-DP and FETI-FETI).
    schur : callable
        W vector -> S w on the interface.

    Returns
    -------
    (F, M) : tuple of callables, shape (n_lambda,) -> (n_lambda,)
    """
    BT = B.T.tocsr()

    def F(lam: np.ndarray) -> np.ndarray:
        return B @ primal_solve(BT @ lam)

    return F, scaled_jump(B_D, schur)


@dataclass
class DualSolution:
    """lambda, the kernel coefficients alpha (None without kernel) and the PCG result."""

    lam: np.ndarray
    alpha: np.ndarray | None
    krylov: KrylovResult


def q_scaled(F: Matvec, M: Matvec, d: np.ndarray, q: np.ndarray | None
             ) -> tuple[np.ndarray, Matvec, Matvec, np.ndarray]:
    """The dual problem in mu = Q^{-1/2} lambda: (Q^{1/2}, Q^{1/2} F Q^{1/2}, Q^{-1/2} M^{-1} Q^{-1/2}, Q^{1/2} d).

    Parameters
    ----------
    F, M : callable
        lambda -> F lambda and lambda -> M^{-1} lambda, shape (n,) -> (n,).
    d : ndarray, shape (n,)
    q : ndarray, shape (n,), or None
        Diagonal of Q (positive); None for Q = I.
    """
    sq = np.ones(d.shape[0]) if q is None else np.sqrt(q)

    def F_scaled(mu: np.ndarray) -> np.ndarray:
        return sq * F(sq * mu)

    def M_scaled(mu: np.ndarray) -> np.ndarray:
        return M(mu / sq) / sq

    return sq, F_scaled, M_scaled, sq * d


def solve_dual(F: Matvec, M: Matvec, d: np.ndarray, G: sp.spmatrix | None, e: np.ndarray | None,
               q: np.ndarray | None = None, *, rtol: float = 1e-6, maxiter: int = 1000,
               cond: bool = False, lam0: np.ndarray | None = None) -> DualSolution:
    """Projected PCG on the dual problem.

    Parameters
    ----------
    F, M : callable
        lambda -> F lambda and the preconditioner lambda -> M^{-1} lambda, shape (n,) -> (n,).
    d : ndarray, shape (n,)
    G : sparse matrix, shape (n, k), or None
        Natural coarse space B R (None or k = 0: no projection).
    e : ndarray, shape (k,)
        R^T f, so that G^T lambda = e.
    q : ndarray, shape (n,), optional
        Diagonal of Q (positive); None for Q = I.
    rtol, maxiter, cond : see :func:`ddsolve.krylov.pcg`.
    lam0 : ndarray, optional
        Warm start; it is corrected to satisfy G^T lambda = e.

    Returns
    -------
    DualSolution
        alpha solves G alpha = F lambda - d in the least-squares sense, so that
        u = A^+ (f - B^T lambda) + R alpha.
    """
    n = d.shape[0]
    if n == 0:              # no multipliers (a tiny mesh whose parts share no node): nothing to iterate
        kr = KrylovResult.solved_directly()
        k = 0 if G is None else G.shape[1]
        return DualSolution(lam=np.zeros(0), alpha=np.zeros(k) if k else None, krylov=kr)
    sq, F_scaled, M_scaled, d_scaled = q_scaled(F, M, d, q)
    mu0 = np.zeros(n) if lam0 is None else lam0 / sq
    projection = None
    if G is not None and G.shape[1] > 0:
        # (2.13) for the scaled coarse space Q^{1/2} G: the orthogonal projection in mu
        projection = Projection((sp.diags(sq) @ G).tocsc(), sparse=True)
        mu0 = projection.apply(mu0) + projection.particular(e)
    kr = pcg(linear_operator(n, F_scaled), d_scaled, mu0, rtol=rtol, maxiter=maxiter,
             M=linear_operator(n, M_scaled), P=None if projection is None else linear_operator(n, projection.apply),
             cond=cond)
    alpha = projection.coefficients(F_scaled(kr.x) - d_scaled) if projection is not None else None
    return DualSolution(lam=sq * kr.x, alpha=alpha, krylov=kr)
