"""Factorizations of the coarse matrix S_PiPi (the primal problem of FETI-DP and BDDC, (2.17)).

:func:`coarse_factor` chooses the backend: MKL PARDISO's Cholesky for coarse matrices with many
stored entries (3D coarse problems with a dense coupling), SuperLU in its symmetric mode
(:func:`symmetric_superlu`) otherwise. Both serial (:class:`ddsolve.dd.primal.PrimalConstrainedSolver`)
and distributed (:mod:`ddsolve.parallel.coarse`) solvers use it.
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

log = logging.getLogger(__name__)

#: Coarse matrices S_PiPi with at least this many stored entries are factored by MKL PARDISO (SPD
#: Cholesky, METIS ordering; :mod:`ddsolve.dd.pardiso`) when it loads, sparser ones by SuperLU, as
#: before. The dense coupling of 3D coarse problems (every edge node primal) is what SuperLU's
#: minimum degree handles badly; 2D coarse matrices stay far below (Table 4's largest, FETI-FETI
#: with 9,212 primal dofs: 80,628 entries). Measured on a 3D DDInverse (order 2, 290,448 dofs,
#: 290 METIS parts, 10,987 primal dofs, 3,677,215 entries, one thread): SuperLU 44.0 s, PARDISO
#: 0.92 s (docs/ngsolve.md, "3D meshes"); most of SuperLU's time went to its default options,
#: which :func:`symmetric_superlu` replaces (a similar matrix: 58.1 s -> 5.9 s).
COARSE_PARDISO_MIN_NNZ = 1_000_000


def coarse_factor(S: sp.spmatrix):
    """A factorization of the coarse matrix ``S`` (n_primal, n_primal) with a ``solve`` method.

    PARDISO's Cholesky for a ``S`` with many entries (:data:`COARSE_PARDISO_MIN_NNZ`); SuperLU
    (minimum degree on S^T + S) otherwise, and where PARDISO fails, see :func:`symmetric_superlu`
    (a ``S`` that is not positive definite gets SuperLU's default pivoting, which factors it or
    reports the singular matrix, as it always did).
    """
    from . import pardiso

    if COARSE_PARDISO_MIN_NNZ <= S.nnz <= pardiso.MAX_NNZ and pardiso.available():
        try:
            return pardiso.PardisoCholesky(S)
        except RuntimeError as exc:
            log.info("coarse problem: PARDISO failed (%s); using SuperLU", exc)
    return symmetric_superlu(S)


def symmetric_superlu(S: sp.spmatrix):
    """SuperLU of a symmetric ``S`` in its symmetric mode with diagonal pivots, so that the
    symmetric minimum degree ordering survives; the default pivoting where ``S`` turns out not
    positive definite.

    SuperLU's defaults (no symmetric mode, threshold pivoting) were slow on coarse matrices: on a
    2D one of 7,511 primal dofs (no row swapped, the same fill) 0.81 s against 0.03 s, the gain
    all from the symmetric mode; on 3D ones the row swaps also undo the ordering (3.78M entries:
    58.1 s and 97.9M factor entries against 5.9 s and 28.4M; 2D with edge averages, 19,477 primal
    dofs: 12.3 s against 0.19 s; a review measured 276 s of a 305 s setup at 8,000 parts). The
    diagonal pivots are kept when they are all positive and no row was swapped (S is then
    positive definite up to rounding; at a zero diagonal entry SuperLU swaps rows even so);
    otherwise ``S`` is factored again with the default pivoting, as before.
    """
    A = sp.csc_matrix(S)
    try:
        lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True, "DiagPivotThresh": 0.0})
        if np.array_equal(lu.perm_r, lu.perm_c) and np.all(lu.U.diagonal() > 0):
            return lu
    except RuntimeError:                         # an exactly singular factor
        pass
    return spla.splu(A, permc_spec="MMD_AT_PLUS_A")
