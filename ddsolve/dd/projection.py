"""Projections onto ker(G^T): the natural coarse space of FETI-type dual problems.

One class serves every method that projects its multipliers onto
V = ker(G^T) (or onto the range of P for a Q-weighted P):

* one-level FETI (Section 2.5, (2.13)-(2.14)): P = I - G (G^T G)^{-1} G^T,
  G = B R, and lambda_0 = G (G^T G)^{-1} e with G^T lambda_0 = e;
* FETI-FETI (Section 3.4, (3.35)): the same with G = Z B~_c R;
* the hybrid method (Section 4.2, (4.5), (4.11), (4.13)): P^k = I - G^k (G^kT G^k)^{-1} G^kT,
  G^k = Z^k B^_{Gamma,c} R_c, and the Q-weighted variants of
  :meth:`ddsolve.multibody.hybrid.HybridSolver.solve`;
* SMALBE on the FETI-DP dual (Section 6.4, (6.17)): P = I - G^T G for the
  orthonormalised single row G (Q = G^T G is the complementary projection).

The Q-weighted projection of Klawonn and Widlund is

    P = I - Q G (G^T Q G)^{-1} G^T,     P^T = I - G (G^T Q G)^{-1} (Q G)^T,

with P^2 = P, range(P) = ker(G^T) and P^T vanishing on range(G); Q = I gives the
orthogonal projection (2.13). The coarse matrix G^T Q G (k x k, k = dim ker of the
floating subdomains or bodies) is factored once in the constructor.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

log = logging.getLogger(__name__)

__all__ = ["Projection"]


class Projection:
    """P = I - Q G (G^T Q G)^{-1} G^T, built once from G (and Q).

    Parameters
    ----------
    G : sparse matrix or ndarray, shape (n, k)
        Natural coarse space (k >= 1 columns, or a 1-D array for one column).
    Q : None, ndarray or callable, optional
        ``None``: Q = I, the orthogonal projection (2.13). A 1-D array of shape
        (n,): the diagonal of Q. A callable (n,) -> (n,): Q applied to the columns
        of G (e.g. the Dirichlet preconditioner M_D^{-1}; Q G is stored dense).
    orthonormal : bool
        G^T G = I is known (e.g. a normalised single row, (6.17)): the orthogonal
        projection is applied as v - G (G^T v), with no coarse solve.
    sparse : bool
        Factor G^T Q G by sparse LU (``splu``) instead of dense Cholesky; for
        many columns (one per floating subdomain in one-level FETI).
    singular_tol : float, optional
        With the dense factorization: raise ``ValueError`` when the smallest
        eigenvalue of G^T Q G is not above ``singular_tol`` times the largest in
        magnitude (``max(|ev|max, 1)`` for the orthogonal projection). An
        indefinite G^T Q G (Q not positive definite) is factored by LU with a
        warning. ``None``: no check (the sparse factorization never checks).
    singular_message : str
        Message of that ``ValueError``.

    Attributes
    ----------
    n, k : int
        Shapes of G.
    G : sparse matrix or ndarray, shape (n, k)
    QG : ndarray or sparse matrix, shape (n, k)
        Q G (``G`` itself for the orthogonal projection).
    orthogonal : bool
    eigenvalues : ndarray or None
        Eigenvalues of G^T Q G when checked.
    """

    def __init__(self, G: Any, Q: None | np.ndarray | Callable[[np.ndarray], np.ndarray] = None, *,
                 orthonormal: bool = False, sparse: bool = False, singular_tol: float | None = None,
                 singular_message: str = "G^T Q G is singular") -> None:
        self._column = None
        if isinstance(G, np.ndarray) and G.ndim == 1:
            self._column = G                      # one dense column: v - g (g . v)
            G = G[:, None]
        self.G = G
        self.n, self.k = G.shape
        self.orthogonal = Q is None
        self.orthonormal = bool(orthonormal) and Q is None
        self.eigenvalues: np.ndarray | None = None
        self._factor: tuple[str, Any] | None = None
        if Q is None:
            self.QG = G
        elif callable(Q):
            Gd = G.toarray() if sp.issparse(G) else np.asarray(G)
            self.QG = np.column_stack([Q(g) for g in Gd.T])
        else:
            q = np.asarray(Q, dtype=float)
            self.QG = (sp.diags(q) @ G).tocsc() if sp.issparse(G) else q[:, None] * G
        if self.orthonormal or self.k == 0:
            return
        if sparse:
            GtQG = (G.T @ self.QG).tocsc() if sp.issparse(G) else sp.csc_matrix(G.T @ self.QG)
            self._factor = ("splu", spla.splu(GtQG))
            return
        Gd = G.toarray() if sp.issparse(G) else np.asarray(G)
        GtQG = Gd.T @ self.QG if Q is not None else (G.T @ G)
        GtQG = GtQG.toarray() if sp.issparse(GtQG) else np.asarray(GtQG)
        if Q is not None:
            GtQG = 0.5 * (GtQG + GtQG.T)
        kind = "cho"
        if singular_tol is not None:
            ev = np.linalg.eigvalsh(GtQG)
            self.eigenvalues = ev
            if Q is None:
                if ev.min() <= singular_tol * max(ev.max(), 1.0):
                    raise ValueError(singular_message)
            else:
                if not np.abs(ev).min() > singular_tol * np.abs(ev).max():
                    raise ValueError(singular_message)
                if ev.min() <= 0:
                    log.warning("projection: G^T Q G is indefinite (min eigenvalue %.2e): Q is not "
                                "positive definite", ev.min())
                    kind = "lu"
        self._factor = (kind, la.cho_factor(GtQG) if kind == "cho" else la.lu_factor(GtQG))

    # ------------------------------------------------------------------ pieces
    def coarse_solve(self, x: np.ndarray) -> np.ndarray:
        """(G^T Q G)^{-1} x, shape (k,) -> (k,)."""
        if self._factor is None:
            return np.asarray(x, dtype=float).copy()
        kind, f = self._factor
        if kind == "splu":
            return f.solve(x)
        return la.cho_solve(f, x) if kind == "cho" else la.lu_solve(f, x)

    def particular(self, e: np.ndarray) -> np.ndarray:
        """lambda_0 = Q G (G^T Q G)^{-1} e, so that G^T lambda_0 = e ((2.13)), shape (k,) -> (n,)."""
        return self.QG @ self.coarse_solve(e)

    def coefficients(self, r: np.ndarray) -> np.ndarray:
        """(G^T Q G)^{-1} G^T r, shape (n,) -> (k,): the kernel amplitudes of a residual r."""
        return self.coarse_solve(self.G.T @ r)

    # ------------------------------------------------------------------- apply
    def apply(self, v: np.ndarray) -> np.ndarray:
        """P v = v - Q G (G^T Q G)^{-1} G^T v, shape (n,) -> (n,)."""
        if self._column is not None and self.orthonormal:
            return v - self._column * (self._column @ v)
        if self.k == 0:
            return v
        return v - self.QG @ self.coarse_solve(self.G.T @ v)

    def apply_transpose(self, w: np.ndarray) -> np.ndarray:
        """P^T w = w - G (G^T Q G)^{-1} (Q G)^T w, zero on range(G), shape (n,) -> (n,)."""
        if self.orthogonal:
            return self.apply(w)
        return w - self.G @ self.coarse_solve(self.QG.T @ w)

    def complement(self, v: np.ndarray) -> np.ndarray:
        """(I - P) v = Q G (G^T Q G)^{-1} G^T v (for an orthonormal G: G G^T v)."""
        if self._column is not None and self.orthonormal:
            return self._column * (self._column @ v)
        return v - self.apply(v)

    __call__ = apply

    def as_operator(self) -> spla.LinearOperator:
        """P as a scipy LinearOperator (``rmatvec`` is P^T)."""
        return spla.LinearOperator((self.n, self.n), matvec=self.apply, rmatvec=self.apply_transpose,
                                   dtype=float)
