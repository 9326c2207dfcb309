"""What every single-body method returns to :func:`ddsolve.api.solve`."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..krylov.result import KrylovResult


@dataclass
class MethodOutput:
    """Solution and diagnostics of one substructuring solve.

    Attributes
    ----------
    u : ndarray, shape (ndof,)
        Global solution.
    krylov : KrylovResult or None
        The outer Krylov iteration (None for direct solves).
    nlambda : int
        Lagrange multipliers (0 for primal methods).
    n_factorizations : int
        Factorizations computed (shared ones counted once).
    setup_seconds : float
        Time to build the operators (factorizations included).
    extra : dict
        Method-specific diagnostics.
    """

    u: np.ndarray
    krylov: KrylovResult | None
    nlambda: int = 0
    n_factorizations: int = 0
    setup_seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
