"""Direct sparse reference solve of the assembled problem."""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse.linalg as spla

from .common import MethodOutput
from .substructure import Substructures


def solve_direct(sub: Substructures) -> MethodOutput:
    """Solve R^T diag(A^(i)) R u = R^T f with a sparse factorization.

    Parameters
    ----------
    sub : Substructures

    Returns
    -------
    MethodOutput
        ``krylov`` is None; one factorization.
    """
    t0 = time.perf_counter()
    A = sub.global_matrix()
    f = sub.assemble_vector(sub.f_W)
    lu = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    setup = time.perf_counter() - t0
    u = lu.solve(f)
    return MethodOutput(u=u, krylov=None, nlambda=0, n_factorizations=1, setup_seconds=setup)
