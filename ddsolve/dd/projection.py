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
from scipy.sparse.csgraph import connected_components

log = logging.getLogger(__name__)

__all__ = ["Projection", "gram_is_singular", "kernel_is_trivial"]

#: Largest k (columns of G) whose G^T Q G is checked and factored dense; beyond it the orthogonal
#: projection of a sparse G is checked from its structure and factored by sparse LU (a review: 3,844
#: floating bodies made a dense 48,006 x 3,844 copy of G, 1.5 GB, and O(k^3) eigensolves and factorizations).
DENSE_COARSE_MAX = 500


def kernel_is_trivial(G: Any) -> bool | None:
    """Whether G v = 0 only for v = 0, read from the structure of G; None where G is not of that form.

    The form: every row ties two columns by opposite entries of equal size, or holds one entry
    (the natural coarse spaces G = B R of floating bodies or subdomains: a multiplier between two
    floating ones, or between a floating one and a clamped one). G v = 0 then forces v equal along
    the two-entry rows and zero at a column of a one-entry row, so ker G = {0} exactly when every
    connected component of the columns (joined by the two-entry rows) holds such a column. One pass
    over the nonzeros and one ``connected_components``: O(nnz), where the eigenvalues of G^T G cost O(k^3).

    Parameters
    ----------
    G : sparse matrix or ndarray, shape (n, k)
    """
    G = sp.csr_matrix(G, copy=True)          # eliminate_zeros works in place: not on the caller's arrays
    G.eliminate_zeros()
    counts = np.diff(G.indptr)
    if counts.max(initial=0) > 2:
        return None
    two = G.indptr[:-1][counts == 2]
    if not np.array_equal(G.data[two], -G.data[two + 1]):
        return None
    k = G.shape[1]
    joined = sp.csr_matrix((np.ones(two.size), (G.indices[two], G.indices[two + 1])), shape=(k, k))
    n_comp, label = connected_components(joined, directed=False)
    held = np.zeros(n_comp, dtype=bool)
    held[label[G.indices[G.indptr[:-1][counts == 1]]]] = True
    return bool(held.all())


def gram_is_singular(G: Any, tol: float) -> bool:
    """Whether G^T G (k x k) is singular: its smallest eigenvalue at most ``tol max(lambda_max, 1)`` for
    k <= :data:`DENSE_COARSE_MAX` (dense), else :func:`kernel_is_trivial` (the eigenvalues where G is not of
    its form). The test of :class:`Projection` with ``singular_tol``, for a caller that factors G^T G itself."""
    k = G.shape[1]
    if k > DENSE_COARSE_MAX and sp.issparse(G):
        trivial = kernel_is_trivial(G)
        if trivial is not None:
            return not trivial
    GtG = G.T @ G
    ev = np.linalg.eigvalsh(GtG.toarray() if sp.issparse(GtG) else np.asarray(GtG))
    return not ev.min() > tol * max(ev.max(), 1.0)


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
        many columns (one per floating subdomain in one-level FETI). The orthogonal
        projection of a sparse G with more than :data:`DENSE_COARSE_MAX` columns and
        a ``singular_tol`` is factored so too, checked by :func:`kernel_is_trivial`.
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
        if Q is None and sp.issparse(G) and self.k > DENSE_COARSE_MAX and singular_tol is not None:
            if gram_is_singular(G, singular_tol):
                raise ValueError(singular_message)
            sparse = True
        if sparse:
            GtQG = (G.T @ self.QG).tocsc() if sp.issparse(G) else sp.csc_matrix(G.T @ self.QG)
            try:
                self._factor = ("splu", spla.splu(GtQG))
            except RuntimeError as exc:                 # "Factor is exactly singular"
                if singular_tol is None:
                    raise
                raise ValueError(singular_message) from exc
            return
        if Q is not None:                               # Q G is dense: so is G^T Q G
            Gd = G.toarray() if sp.issparse(G) else np.asarray(G)
            GtQG = Gd.T @ self.QG
        else:                                           # G^T G from sparse G, no dense copy of G
            GtQG = G.T @ G
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
