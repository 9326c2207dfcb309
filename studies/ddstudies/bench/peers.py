"""Peer solvers for sparse SPD systems: direct factorizations and pyamg + CG.

:func:`direct_solver` factors a scipy sparse SPD matrix with one of the
:data:`DIRECT_SOLVERS` backends and returns the factorization time and a
solve function; :func:`pyamg_cg` runs smoothed-aggregation AMG as a
preconditioner of CG. Backends whose package is missing raise
:class:`BackendUnavailable` (an ``ImportError``) naming the pip package.

Backends, with the single-core CPU time of factor + solve for the Q1
Poisson matrix of structured_square(1, 8, 64) (261,121 dofs) on the 2-core
development machine (README, benchmark section):

``mkl-pardiso`` (0.54 s, the default :data:`DEFAULT_DIRECT`)
    Intel MKL PARDISO called directly through ctypes (SPD type 2, minimum
    degree ordering, upper triangle of the scipy matrix); needs the ``mkl``
    wheel (pinned in environment.txt).
``pardiso`` (1.31 s, of which 0.6 s converting to an NGSolve matrix)
    Intel MKL PARDISO through NGSolve (``inverse="pardisospd"``, the SPD
    matrix type); needs the ``mkl`` wheel, which NGSolve finds at run time.
``sparsecholesky`` (2.35 s)
    NGSolve's own sparse Cholesky factorization.
``cholmod`` (2.54 s through cholespy)
    SuiteSparse CHOLMOD, through ``scikit-sparse`` (``sksparse.cholmod``)
    when installed, otherwise through ``cholespy`` (scikit-sparse has no
    wheel; neither is pinned).
``superlu`` (1.49 s)
    SciPy's SuperLU with the options of :func:`ddsolve.dd.solve_direct`
    (MMD on A^T + A, symmetric mode).

The NGSolve backends include the conversion of the scipy matrix into an
NGSolve sparse matrix in ``factor_seconds``. For comparison, :func:`pyamg_cg`
(smoothed aggregation + CG to rtol 1e-8, 9 iterations) took 0.68 s.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from threadpoolctl import threadpool_limits

#: A solve function: right-hand side (n,) -> solution (n,).
SolveFn = Callable[[np.ndarray], np.ndarray]


class BackendUnavailable(ImportError):
    """A solver backend whose package is not installed (or not usable)."""


class Factorization(NamedTuple):
    """A factored matrix: ``factor_seconds, solve = direct_solver(name, A)``.

    Attributes
    ----------
    factor_seconds : float
        Wall time of the factorization (format conversion included).
    solve : callable
        ``solve(b) -> x`` with A x = b, b of shape (n,).
    """

    factor_seconds: float
    solve: SolveFn


def _superlu(A: sp.csr_matrix, threads: int) -> SolveFn:
    lu = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    return lu.solve


def _ngsolve_matrix(A: sp.csr_matrix):
    try:
        import ngsolve  # noqa: F401
        from ngsolve.la import SparseMatrixd
    except ImportError as exc:  # pragma: no cover - ngsolve is a core dependency
        raise BackendUnavailable("NGSolve backends need the 'ngsolve' package") from exc
    coo = A.tocoo()
    return SparseMatrixd.CreateFromCOO(coo.row.astype(np.int64), coo.col.astype(np.int64),
                                       coo.data.astype(np.float64), A.shape[0], A.shape[1])


def _ngsolve_inverse(A: sp.csr_matrix, threads: int, inverse: str) -> SolveFn:
    import contextlib

    import ngsolve as ngs

    M = _ngsolve_matrix(A)

    def parallel():
        # one thread: no task manager (NGSolve and MKL PARDISO then run sequentially)
        if threads <= 1:
            return contextlib.nullcontext()
        ngs.SetNumThreads(int(threads))
        return ngs.TaskManager()

    try:
        with parallel():
            Minv = M.Inverse(inverse=inverse)
    except RuntimeError as exc:
        if "not available" in str(exc):
            raise BackendUnavailable(f"NGSolve inverse {inverse!r} is not available: {exc} "
                                     "(pip install mkl)") from exc
        raise
    b_vec, x_vec = M.CreateColVector(), M.CreateColVector()

    def solve(b: np.ndarray) -> np.ndarray:
        b_vec.FV().NumPy()[:] = b
        with parallel():
            x_vec.data = Minv * b_vec
        return np.array(x_vec.FV().NumPy(), copy=True)

    return solve


def _pardiso(A: sp.csr_matrix, threads: int) -> SolveFn:
    from importlib.metadata import PackageNotFoundError, version

    try:
        version("mkl")
    except PackageNotFoundError as exc:
        raise BackendUnavailable("backend 'pardiso' needs Intel MKL: pip install mkl "
                                 "(NGSolve loads libmkl_rt from the mkl wheel)") from exc
    return _ngsolve_inverse(A, threads, "pardisospd")


def _sparsecholesky(A: sp.csr_matrix, threads: int) -> SolveFn:
    return _ngsolve_inverse(A, threads, "sparsecholesky")


def _mkl_library():
    """ctypes handle of libmkl_rt from the ``mkl`` wheel (as NGSolve locates it), or None."""
    import ctypes
    import ctypes.util
    from importlib.metadata import PackageNotFoundError, distribution

    try:
        dist = distribution("mkl")
    except PackageNotFoundError:
        return None
    paths = [str(dist.locate_file(f)) for f in dist.files or [] if "mkl_rt" in str(f)]
    path = paths[0] if paths else ctypes.util.find_library("mkl_rt")
    if path is None:
        return None
    try:
        return ctypes.CDLL(path)
    except OSError:
        return None


#: iparm[1] of the direct MKL PARDISO backend: 0 minimum degree, 2 METIS, 3 parallel METIS.
PARDISO_ORDERING = 0


def _mkl_pardiso(A: sp.csr_matrix, threads: int) -> SolveFn:
    """MKL PARDISO called directly (SPD type 2) on the upper triangle of the scipy matrix."""
    import ctypes
    import weakref

    lib = _mkl_library()
    if lib is None or not hasattr(lib, "pardiso"):
        raise BackendUnavailable("backend 'mkl-pardiso' needs Intel MKL: pip install mkl")
    upper = sp.triu(A, format="csr")
    upper.sort_indices()
    n = A.shape[0]
    data = np.ascontiguousarray(upper.data, dtype=np.float64)
    indptr = np.ascontiguousarray(upper.indptr, dtype=np.int32)
    indices = np.ascontiguousarray(upper.indices, dtype=np.int32)
    handle = np.zeros(64, dtype=np.int64)          # PARDISO's internal pointers, pt[64]
    iparm = np.zeros(64, dtype=np.int32)
    iparm[[0, 1, 9, 34]] = 1, PARDISO_ORDERING, 8, 1   # own iparm, fill-in ordering, perturbation 1e-8, 0-based
    ints = {k: ctypes.c_int32(v) for k, v in (("maxfct", 1), ("mnum", 1), ("mtype", 2), ("n", n),
                                                ("nrhs", 1), ("msglvl", 0))}
    ptr = np.ctypeslib.as_ctypes
    set_threads = getattr(lib, "MKL_Set_Num_Threads_Local", None)

    def call(phase: int, b: np.ndarray, x: np.ndarray) -> None:
        error = ctypes.c_int32(0)
        old = set_threads(ctypes.c_int(max(int(threads), 1))) if set_threads else None
        try:
            lib.pardiso(ptr(handle), ctypes.byref(ints["maxfct"]), ctypes.byref(ints["mnum"]),
                        ctypes.byref(ints["mtype"]), ctypes.byref(ctypes.c_int32(phase)),
                        ctypes.byref(ints["n"]), ptr(data), ptr(indptr), ptr(indices), None,
                        ctypes.byref(ints["nrhs"]), ptr(iparm), ctypes.byref(ints["msglvl"]),
                        ptr(b), ptr(x), ctypes.byref(error))
        finally:
            if old is not None:
                set_threads(ctypes.c_int(old))
        if error.value != 0:
            raise RuntimeError(f"MKL PARDISO error {error.value} in phase {phase}")

    dummy = np.zeros(1)
    call(12, dummy, dummy)                          # analysis and numerical factorization

    def solve(b: np.ndarray) -> np.ndarray:
        rhs = np.array(b, dtype=np.float64, copy=True)
        x = np.zeros(n)
        call(33, rhs, x)
        return x

    # phase -1 releases PARDISO's memory when the solve function is collected
    weakref.finalize(solve, call, -1, dummy, dummy)
    return solve


def _cholmod(A: sp.csr_matrix, threads: int) -> SolveFn:
    csc = A.tocsc()
    try:
        from sksparse.cholmod import cholesky
    except ImportError:
        pass
    else:
        return cholesky(csc)
    try:
        import cholespy
    except ImportError as exc:
        raise BackendUnavailable("backend 'cholmod' needs 'scikit-sparse' or 'cholespy' "
                                 "(pip install cholespy)") from exc
    n = A.shape[0]
    solver = cholespy.CholeskySolverD(n, csc.indptr.astype(np.int32), csc.indices.astype(np.int32),
                                      csc.data.astype(np.float64), cholespy.MatrixType.CSC)

    def solve(b: np.ndarray) -> np.ndarray:
        x = np.zeros(n)
        solver.solve(np.ascontiguousarray(b, dtype=np.float64), x)
        return x

    return solve


#: Direct backends: name -> factory(A, threads) -> solve function.
DIRECT_SOLVERS: dict[str, Callable[[sp.csr_matrix, int], SolveFn]] = {
    "mkl-pardiso": _mkl_pardiso,
    "pardiso": _pardiso,
    "sparsecholesky": _sparsecholesky,
    "cholmod": _cholmod,
    "superlu": _superlu,
}

#: The fastest backend that installs from environment.txt (README, benchmark section).
DEFAULT_DIRECT = "mkl-pardiso"


def direct_solver(name: str, A: sp.spmatrix, *, threads: int = 1) -> Factorization:
    """Factor the SPD matrix ``A`` with backend ``name``.

    Parameters
    ----------
    name : str
        A key of :data:`DIRECT_SOLVERS`.
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite (both triangles stored).
    threads : int
        BLAS threads (threadpoolctl) and NGSolve task-manager threads (which
        MKL PARDISO also uses) during the factorization and the solves.

    Returns
    -------
    Factorization
        ``(factor_seconds, solve)``.

    Raises
    ------
    KeyError
        Unknown backend name.
    BackendUnavailable
        The backend's package is not installed.
    """
    if name not in DIRECT_SOLVERS:
        raise KeyError(f"unknown direct solver {name!r} (choose from {', '.join(DIRECT_SOLVERS)})")
    A = sp.csr_matrix(A, dtype=np.float64)
    with threadpool_limits(limits=threads, user_api="blas"):
        t0 = time.perf_counter()
        inner = DIRECT_SOLVERS[name](A, threads)
        seconds = time.perf_counter() - t0

    def solve(b: np.ndarray) -> np.ndarray:
        with threadpool_limits(limits=threads, user_api="blas"):
            return np.asarray(inner(np.asarray(b, dtype=np.float64)), dtype=np.float64).reshape(-1)

    return Factorization(seconds, solve)


def available_direct_solvers() -> list[str]:
    """Backends of :data:`DIRECT_SOLVERS` whose packages import (checked on a 2 x 2 matrix)."""
    out = []
    A = sp.csr_matrix(np.array([[2.0, -1.0], [-1.0, 2.0]]))
    for name in DIRECT_SOLVERS:
        try:
            direct_solver(name, A)
        except BackendUnavailable:
            continue
        out.append(name)
    return out


@dataclass
class PeerResult:
    """Outcome of an iterative peer solve.

    Attributes
    ----------
    x : ndarray, shape (n,)
    converged : bool
        ||b - A x||_2 <= rtol ||b||_2 (zero initial guess, so ||r_0|| = ||b||).
    iterations : int
    setup_seconds, solve_seconds : float
        AMG hierarchy construction; CG iterations.
    residuals : ndarray, shape (iterations + 1,)
        ||r_k||_2 as reported by pyamg.
    """

    x: np.ndarray
    converged: bool
    iterations: int
    setup_seconds: float
    solve_seconds: float
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))


def pyamg_cg(A: sp.spmatrix, b: np.ndarray, rtol: float, *, maxiter: int = 1000, threads: int = 1) -> PeerResult:
    """Smoothed-aggregation AMG (pyamg defaults, symmetric) as a preconditioner of CG.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        SPD.
    b : ndarray, shape (n,)
    rtol : float
        Stopping rule ||r_k||_2 < rtol ||r_0||_2 with x_0 = 0.
    maxiter : int
    threads : int
        BLAS threads.

    Returns
    -------
    PeerResult

    Raises
    ------
    BackendUnavailable
        pyamg is not installed.
    """
    try:
        import pyamg
    except ImportError as exc:
        raise BackendUnavailable("pyamg_cg needs 'pyamg' (pip install pyamg)") from exc
    A = sp.csr_matrix(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    with threadpool_limits(limits=threads, user_api="blas"):
        t0 = time.perf_counter()
        ml = pyamg.smoothed_aggregation_solver(A, symmetry="symmetric")
        t1 = time.perf_counter()
        residuals: list[float] = []
        x = ml.solve(b, x0=np.zeros_like(b), tol=rtol, maxiter=maxiter, accel="cg", residuals=residuals)
        t2 = time.perf_counter()
    res = np.asarray(residuals, dtype=float)
    b_norm = float(np.linalg.norm(b))
    converged = bool(np.linalg.norm(b - A @ x) <= rtol * b_norm * (1 + 1e-8)) if b_norm > 0 else True
    return PeerResult(x=np.asarray(x, dtype=float), converged=converged, iterations=max(res.size - 1, 0),
                      setup_seconds=t1 - t0, solve_seconds=t2 - t1, residuals=res)
