"""Result dataclass shared by the Krylov solvers."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class KrylovResult:
    """Outcome of a Krylov iteration.

    Attributes
    ----------
    x : ndarray, shape (n,)
        Final iterate.
    converged : bool
        True when ||r_k|| <= max(rtol * ||r_0||, atol) for the recursive
        residual, the recomputed residual ``true_residual`` meets it too (within
        the policy factor, see ``attained``) and all values are finite.
    reason : str
        One-line reason for stopping, e.g. ``"converged: ||r||/||r0|| = 3.1e-07 < 1e-06"``,
        ``"maxiter 200 reached"`` or ``"breakdown: <p, A p> <= 0"``.
    iterations : int
        Number of iterations performed.
    residuals : ndarray, shape (iterations + 1,)
        ||r_k|| for k = 0..iterations (the recursively updated residual) in the
        stopping norm: ||.||_2, or ||r||_M = <r, M r>^{1/2} for ``pcr(norm="M")``.
    lambda_min, lambda_max, cond : float or None
        Lanczos estimates of the extreme eigenvalues of the preconditioned
        operator and their ratio (PCG with ``cond=True`` only).
    matvecs : int
        Number of operator applications.
    seconds : float
        Wall time of the iteration.
    true_residual : float or None
        ||P (b - A x)|| (||b - A x|| without a projection ``P``, in the norm of
        ``residuals``) recomputed
        from the returned ``x`` with one extra operator application, to compare
        with the recursively updated ``residuals[-1]``.
    attained : bool or None
        Whether ``true_residual`` is finite and within
        :data:`~ddsolve.krylov.convergence.TRUE_RESIDUAL_FACTOR` of the
        threshold ``max(rtol ||r_0||, atol)`` (None where not computed). A
        result is ``converged`` only if this holds.
    restarts : int
        Number of restarts (0 for a single cycle; see
        :meth:`~ddsolve.krylov.base.KrylovSolver.restarted`).
    """

    x: np.ndarray
    converged: bool
    reason: str
    iterations: int
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lambda_min: float | None = None
    lambda_max: float | None = None
    cond: float | None = None
    matvecs: int = 0
    seconds: float = 0.0
    true_residual: float | None = None
    attained: bool | None = None
    restarts: int = 0

    @classmethod
    def solved_directly(cls, n: int = 0, what: str = "dual interface") -> "KrylovResult":
        """The result of a system with nothing to iterate on (no ``what`` unknowns on any rank: a tiny
        mesh whose interface nodes are all primal, or that has none): x = 0 of length ``n`` (this rank's
        share), converged at 0 iterations; the caller's direct solves give the answer."""
        return cls(x=np.zeros(n), converged=True, reason=f"no {what}: solved directly", iterations=0,
                   residuals=np.zeros(1))
