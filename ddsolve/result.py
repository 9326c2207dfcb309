"""The result of one :func:`ddsolve.solve` call."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Keys of :meth:`SolveResult.to_dict`, in output order (the JSON of ``ddsolve solve --json``).
SCALAR_KEYS: tuple[str, ...] = (
    "problem", "method", "bodies", "subdomains", "elements", "ndof", "nlambda",
    "converged", "reason", "iterations", "true_residual", "cond", "lambda_min", "lambda_max",
    "error_vs_direct", "setup_seconds", "solve_seconds", "n_factorizations",
)


def _jsonable(value: Any) -> Any:
    """Convert numpy scalars to Python scalars, NaN/inf to ``None``."""
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        return [_jsonable(v) for v in value.tolist()]
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


@dataclass(frozen=True)
class SolveResult:
    """Outcome of solving one scene with one method (built once by :func:`ddsolve.solve`, immutable).

    Attributes
    ----------
    problem, method : str
        Problem kind (``"poisson"``, ...) and solver name (``"feti"``, ...).
    bodies, subdomains, elements : int
        1/H_b, H_b/H_s and H_s/h of the structured scene; on an unstructured mesh the bodies, the METIS
        parts per body and 0 (no element count per subdomain side).
    ndof : int
        Number of global (assembled, Dirichlet-free) degrees of freedom.
    nlambda : int
        Number of Lagrange multipliers (0 for primal and direct methods).
    converged : bool
        Whether the stopping rule ||r_k|| / ||r_0|| <= rtol was met (for the
        Krylov methods also by the recomputed residual, up to a factor 10:
        :func:`ddsolve.api.attained`).
    reason : str
        Why the iteration stopped (human readable, one line).
    iterations : int
        Krylov iterations.
    residuals : ndarray, shape (iterations + 1,), or (0,)
        Residual norms ||r_k||_2, k = 0..iterations (recursively updated by
        the Krylov method); empty for the direct methods and the contact methods (whose
        ``iterations`` sum several solves: see ``extra``).
    true_residual : float or None
        The Krylov residual recomputed from the final iterate, ||P (b - A x)||_2
        (:attr:`ddsolve.krylov.KrylovResult.true_residual`), in the units of
        ``residuals``: compare it with ``residuals[-1]``. None for direct and
        contact solves.
    cond, lambda_min, lambda_max : float or None
        Lanczos estimates (only with ``cond=True``).
    error_vs_direct : float or None
        Relative energy-norm error ||u - u_direct||_A / ||u_direct||_A (only with ``check=True``).
    setup_seconds, solve_seconds : float
        Wall time of setup (assembly, factorizations) and of the iteration.
    n_factorizations : int
        Number of sparse/dense factorizations computed for this solve.
    u : ndarray or None, shape (ndof,)
        Global solution (not part of :meth:`to_dict`).
    extra : dict
        Method-specific scalars or lists (added to :meth:`to_dict`).
    """

    problem: str
    method: str
    bodies: int
    subdomains: int
    elements: int
    ndof: int = 0
    nlambda: int = 0
    converged: bool = False
    reason: str = ""
    iterations: int = 0
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cond: float | None = None
    lambda_min: float | None = None
    lambda_max: float | None = None
    error_vs_direct: float | None = None
    setup_seconds: float = 0.0
    solve_seconds: float = 0.0
    n_factorizations: int = 0
    u: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    true_residual: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable scalar summary (keys :data:`SCALAR_KEYS` plus ``extra``)."""
        out = {key: _jsonable(getattr(self, key)) for key in SCALAR_KEYS}
        out.update({key: _jsonable(val) for key, val in self.extra.items()})
        return out
