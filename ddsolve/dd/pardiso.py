"""Intel MKL PARDISO for sparse SPD matrices, called through ctypes (optional backend).

The pinned ``mkl`` wheel ships ``libmkl_rt`` but no Python module; this module
loads the library from the wheel's files (as NGSolve does) and calls
``pardiso`` directly: real symmetric positive definite matrix type (mtype 2,
Cholesky with diagonal pivots only, no pivoting across the symmetric
ordering), upper triangle in 0-based CSR, one thread (as every local solve of
ddsolve), METIS nested-dissection ordering. Nothing is imported or loaded until
:func:`available` or :class:`PardisoCholesky` is called, so the library works
unchanged without MKL (:mod:`ddsolve.dd.local` then uses SuperLU).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging
import weakref
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

#: iparm[1], the fill-reducing ordering: 0 minimum degree, 2 METIS nested dissection.
#: Measured on the block-diagonal K_rr of 1,094,241 dofs / 1,024 METIS subdomains (1,160,813
#: unknowns, one thread, CPU seconds): METIS analysis 3.5 s + factor 0.6 s, solve 0.08-0.13 s,
#: 387 MB; minimum degree 3.2 s + 1.5 s, solve 0.12 s; the natural (W) order 1.0 s + 1.7 s but
#: 966 MB and slower multi-column solves (docs/performance.md).
ORDERING = 2
#: Threads of the PARDISO calls (ddsolve's local solves run with one BLAS thread).
THREADS = 1
#: PARDISO's 32-bit interface: matrices with more stored entries use SuperLU.
MAX_NNZ = 2 ** 31 - 1


@lru_cache(maxsize=1)
def _library() -> Any:
    """ctypes handle of ``libmkl_rt`` from the ``mkl`` wheel, or None when it is missing."""
    from importlib.metadata import PackageNotFoundError, distribution

    try:
        dist = distribution("mkl")
    except PackageNotFoundError:
        return None
    paths = sorted(str(dist.locate_file(f)) for f in dist.files or [] if "libmkl_rt" in str(f))
    path = paths[0] if paths else ctypes.util.find_library("mkl_rt")
    if path is None:
        return None
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        return None
    return lib if hasattr(lib, "pardiso") else None


def available() -> bool:
    """Whether MKL PARDISO can be called (the ``mkl`` wheel is installed and loads)."""
    return _library() is not None


class PardisoCholesky:
    """Factorization K = L D L^T (SPD, PARDISO mtype 2) of one sparse matrix; multi-column solves.

    Parameters
    ----------
    K : sparse matrix, shape (n, n)
        Symmetric positive definite; only its upper triangle is read.
    order : ndarray of int, shape (n,), optional
        A fill-reducing ordering (unknown ``order[k]`` is eliminated k-th;
        PARDISO's user permutation, iparm[4] = 1) instead of :data:`ORDERING`.

    Raises
    ------
    ImportError
        MKL is not available.
    RuntimeError
        PARDISO reports an error (e.g. -4: the matrix is not positive definite).
    """

    def __init__(self, K: sp.spmatrix, order: np.ndarray | None = None) -> None:
        lib = _library()
        if lib is None:
            raise ImportError("MKL PARDISO needs the mkl wheel (pip install mkl)")
        self.n = int(K.shape[0])
        self._data, self._indptr, self._indices = _upper_triangle(K)
        self._handle = np.zeros(64, dtype=np.int64)             # PARDISO's internal pointers pt[64]
        self._iparm = np.zeros(64, dtype=np.int32)
        # own iparm; ordering; pivot perturbation 1e-8 (unused for SPD); 0-based indices
        self._iparm[[0, 1, 9, 34]] = 1, ORDERING, 8, 1
        self._perm = np.zeros(1, dtype=np.int32)
        if order is not None:
            self._perm = np.ascontiguousarray(order, dtype=np.int32)
            if self._perm.shape != (self.n,):
                raise ValueError(f"order: need shape ({self.n},), got {self._perm.shape}")
            self._iparm[4] = 1
        self._lib = lib
        self._call(12, np.zeros(1), np.zeros(1), 1)             # analysis and numerical factorization
        weakref.finalize(self, _release, lib, self._handle, self._iparm, self.n)

    def _call(self, phase: int, b: np.ndarray, x: np.ndarray, nrhs: int) -> None:
        _pardiso(self._lib, self._handle, self._iparm, phase, self.n, self._data, self._indptr, self._indices,
                 b, x, nrhs, self._perm)

    def solve(self, B: np.ndarray) -> np.ndarray:
        """K^{-1} B for B of shape (n,) or (n, k)."""
        B = np.asarray(B, dtype=np.float64)
        if B.ndim == 2 and B.shape[1] == 0:
            return np.zeros(B.shape)
        nrhs = 1 if B.ndim == 1 else B.shape[1]
        rhs = np.array(B, dtype=np.float64, order="F", copy=True)  # PARDISO may overwrite b
        X = np.empty(B.shape, dtype=np.float64, order="F")
        self._call(33, rhs, X, nrhs)
        return X


def _upper_triangle(K: sp.spmatrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR arrays (data, indptr, indices; float64, int32, int32) of the upper triangle of K, sorted rows.

    One mask over the stored entries (no COO round trip as in ``scipy.sparse.triu``).
    """
    K = sp.csr_matrix(K)
    if not K.has_sorted_indices:
        K = K.sorted_indices()
    n = K.shape[0]
    rows = np.repeat(np.arange(n, dtype=np.int32), np.diff(K.indptr))
    keep = K.indices >= rows
    indptr = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(np.bincount(rows[keep], minlength=n), out=indptr[1:])
    return (np.ascontiguousarray(K.data[keep], dtype=np.float64), indptr,
            np.ascontiguousarray(K.indices[keep], dtype=np.int32))


def _pardiso(lib: Any, handle: np.ndarray, iparm: np.ndarray, phase: int, n: int, data: np.ndarray,
             indptr: np.ndarray, indices: np.ndarray, b: np.ndarray, x: np.ndarray, nrhs: int,
             perm: np.ndarray | None = None) -> None:
    error = ctypes.c_int32(0)
    set_threads = getattr(lib, "MKL_Set_Num_Threads_Local", None)
    old = set_threads(ctypes.c_int(THREADS)) if set_threads else None
    ptr = np.ctypeslib.as_ctypes
    c32 = ctypes.c_int32
    try:
        lib.pardiso(ptr(handle), ctypes.byref(c32(1)), ctypes.byref(c32(1)), ctypes.byref(c32(2)),
                    ctypes.byref(c32(phase)), ctypes.byref(c32(n)), ptr(data), ptr(indptr), ptr(indices),
                    None if perm is None else ptr(perm),
                    ctypes.byref(c32(nrhs)), ptr(iparm), ctypes.byref(c32(0)),
                    b.ctypes.data_as(ctypes.c_void_p), x.ctypes.data_as(ctypes.c_void_p), ctypes.byref(error))
    finally:
        if set_threads is not None:
            set_threads(ctypes.c_int(old))
    if error.value != 0:
        raise RuntimeError(f"MKL PARDISO error {error.value} in phase {phase}"
                           + (" (matrix not positive definite)" if error.value == -4 else ""))


def _release(lib: Any, handle: np.ndarray, iparm: np.ndarray, n: int) -> None:
    """Phase -1: free PARDISO's memory of one factorization."""
    dummy = np.zeros(1)
    try:
        _pardiso(lib, handle, iparm, -1, n, dummy, np.zeros(n + 1, dtype=np.int32), np.zeros(1, dtype=np.int32),
                 dummy, dummy, 1)
    except Exception:  # noqa: BLE001 - never raise from a finalizer
        log.debug("MKL PARDISO: releasing a factorization failed", exc_info=True)
