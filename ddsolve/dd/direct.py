"""Direct sparse reference solve of the assembled problem."""
from __future__ import annotations

import time

import numpy as np

from .common import MethodOutput
from .substructure import Substructures


def solve_direct(sub: Substructures) -> MethodOutput:
    """Solve R^T diag(A^(i)) R u = R^T f with a sparse factorization.

    The factorization is SuperLU (MMD on A^T + A, symmetric mode) with the
    scale-invariant singularity test of
    :func:`ddsolve.multibody.direct.factorize_spd` (pivots relative to their
    own rows' and columns' diagonal entries).

    Parameters
    ----------
    sub : Substructures

    Returns
    -------
    MethodOutput
        ``krylov`` is None; one factorization. If the matrix is numerically
        singular or the solution is not finite, ``u`` is NaN and ``krylov`` is
        a zero-iteration result with ``converged=False`` and the reason
        (nothing is raised).
    """
    from ..multibody.direct import (
        SingularMatrixError,
        factorize_spd,
        failed_direct_solve,
    )

    t0 = time.perf_counter()
    A = sub.global_matrix()
    f = sub.assemble_vector(sub.f_W)
    try:
        solve = factorize_spd(A, "the assembled matrix is singular")
    except SingularMatrixError as exc:
        return MethodOutput(u=np.full(A.shape[0], np.nan), krylov=failed_direct_solve(A.shape[0], str(exc)),
                            nlambda=0, n_factorizations=1, setup_seconds=time.perf_counter() - t0)
    setup = time.perf_counter() - t0
    u = solve(f)
    if not np.all(np.isfinite(u)):
        return MethodOutput(u=u, krylov=failed_direct_solve(u.size, "non-finite solution of the direct solve"),
                            nlambda=0, n_factorizations=1, setup_seconds=setup)
    return MethodOutput(u=u, krylov=None, nlambda=0, n_factorizations=1, setup_seconds=setup)
