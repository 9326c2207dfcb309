"""Direct reference for the equality-constrained multibody problem.

min 1/2 u^T A u - f^T u  subject to  u_a = u_b for every active global pair,
with A the block-diagonal (over bodies) assembled stiffness; floating bodies
make A singular. The constraints are eliminated exactly by merging the dofs
they identify (connected components of the constraint graph): u = T v, and
T^T A T v = T^T f is SPD once every floating body is tied to a clamped one.

The singularity test is scale-invariant (:func:`factorize_spd`): each pivot of
the sparse LU factorization is compared with the diagonal entries of its own
row and column, not with the largest diagonal entry of the matrix, so bodies
or subdomains whose coefficients differ by any factor are not mistaken for
floating ones.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse import csgraph

from ..dd.common import MethodOutput
from ..dd.substructure import Substructures
from ..krylov.result import KrylovResult
from .interface import GlobalInterface

#: A pivot below this multiple of sqrt(|A_ii| |A_jj|) (its own row i and column
#: j) marks the matrix as numerically singular (a floating body or subdomain).
RELATIVE_PIVOT_TOL = 1e-12


class SingularMatrixError(ValueError):
    """The matrix is (numerically) singular; the message says why."""


def relative_pivots(lu: spla.SuperLU, A: sp.spmatrix) -> np.ndarray:
    """``|U_kk| / sqrt(|A_rr| |A_cc|)``, (n,), with r, c the row and column of pivot k.

    ``Pr A Pc = L U`` (SuperLU); the pivot ``U_kk`` eliminates row
    ``perm_r^{-1}(k)`` and column ``perm_c^{-1}(k)`` of ``A``. Invariant under
    ``A -> D A D`` for a positive diagonal ``D`` when the pivot order is kept
    (e.g. bodies or subdomains with different coefficients).
    """
    d = np.abs(np.asarray(A.diagonal(), dtype=float))
    rows = np.argsort(lu.perm_r)
    cols = np.argsort(lu.perm_c)
    ref = np.sqrt(d[rows]) * np.sqrt(d[cols])
    piv = np.abs(lu.U.diagonal())
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ref > 0.0, piv / ref, np.where(piv > 0.0, np.inf, 0.0))


def factorize_spd(A: sp.spmatrix, what: str) -> Callable[[np.ndarray], np.ndarray]:
    """Sparse LU (SuperLU, MMD on A^T + A, symmetric mode) with a scale-invariant singularity test.

    Parameters
    ----------
    A : sparse matrix, shape (n, n)
        Symmetric positive (semi)definite.
    what : str
        Diagnosis used in the error message when ``A`` is singular.

    Returns
    -------
    callable
        ``solve(b) -> x``.

    Raises
    ------
    SingularMatrixError
        If a relative pivot (:func:`relative_pivots`) is below
        :data:`RELATIVE_PIVOT_TOL`, the factorization fails, or ``A`` has
        non-finite entries.
    """
    A = sp.csc_matrix(A)
    if A.nnz and not np.all(np.isfinite(A.data)):
        raise SingularMatrixError("the matrix has non-finite entries")
    try:
        lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    except RuntimeError as exc:          # "Factor is exactly singular"
        raise SingularMatrixError(f"{what} (the factorization failed: {exc})") from exc
    rel = relative_pivots(lu, A)
    worst = float(rel.min()) if rel.size else math.inf
    if not worst >= RELATIVE_PIVOT_TOL:
        raise SingularMatrixError(f"{what} (relative pivot {worst:.1e} < {RELATIVE_PIVOT_TOL:.0e})")
    return lu.solve


def failed_direct_solve(n: int, reason: str) -> KrylovResult:
    """The result of a direct solve that failed: ``converged=False`` with ``reason``, no iterations.

    A direct solver reports failure through ``MethodOutput.krylov`` (None when
    it succeeded), so that :func:`ddsolve.solve` returns ``converged=False``
    with this reason instead of raising.
    """
    return KrylovResult(x=np.full(n, np.nan), converged=False, reason=reason, iterations=0,
                        residuals=np.zeros(0), attained=False)


def merge_matrix(sub: Substructures, gi: GlobalInterface, active: np.ndarray) -> sp.csr_matrix:
    """T, shape (ndof, n_merged): columns are the classes of dofs tied by active constraints."""
    dofs = sub.dof_of_node[gi.pair_nodes[active]]
    graph = sp.csr_matrix((np.ones(len(dofs)), (dofs[:, 0], dofs[:, 1])), shape=(sub.ndof, sub.ndof))
    n_comp, label = csgraph.connected_components(graph, directed=False)
    return sp.csr_matrix((np.ones(sub.ndof), (np.arange(sub.ndof), label)), shape=(sub.ndof, n_comp))


def solve_constrained_direct(sub: Substructures, gi: GlobalInterface, active: np.ndarray) -> MethodOutput:
    """Sparse direct solve of the equality-constrained multibody problem.

    Returns
    -------
    MethodOutput
        ``u`` has shape (ndof,), one value per body copy of each node;
        ``krylov`` is None. If the merged matrix is singular (a floating body
        not tied to a clamped body by the active constraints, by a
        scale-invariant pivot test) or the solution is not finite, ``u`` is
        NaN and ``krylov`` is a :func:`failed_direct_solve` result with
        ``converged=False`` and the reason; nothing is raised.
    """
    T = merge_matrix(sub, gi, active)
    A = (T.T @ sub.global_matrix() @ T).tocsc()
    f = T.T @ sub.assemble_vector(sub.f_W)
    try:
        solve = factorize_spd(A, "a floating body is not tied to a clamped body by the active constraints")
    except SingularMatrixError as exc:
        return MethodOutput(u=np.full(sub.ndof, np.nan), krylov=failed_direct_solve(sub.ndof, str(exc)),
                            nlambda=0, n_factorizations=1)
    u = T @ solve(f)
    if not np.all(np.isfinite(u)):
        return MethodOutput(u=u, krylov=failed_direct_solve(sub.ndof, "non-finite solution of the direct solve"),
                            nlambda=0, n_factorizations=1)
    return MethodOutput(u=u, krylov=None, nlambda=0, n_factorizations=1)
