"""Result dataclass shared by the quadratic programming solvers (MPRGP, SMALBE)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class QPResult:
    """Outcome of :func:`ddsolve.qp.mprgp` or :func:`ddsolve.qp.smalbe`.

    Attributes
    ----------
    x : ndarray, shape (n,)
        Final iterate (always feasible with respect to the bounds ``x >= lb``).
    converged : bool
        Whether the stopping rule was met (see the solver docstrings).
    reason : str
        One-line reason for stopping, e.g.
        ``"converged: ||g^P|| = 3.1e-07 <= 1.0e-06"`` or ``"maxiter 200 reached"``.
    iterations : int
        MPRGP: number of MPRGP steps (CG + expansion + proportioning).
        SMALBE: total number of MPRGP steps over all outer iterations.
    outer_iterations : int
        SMALBE only: number of outer (multiplier update) iterations.
    inner_iterations : list of int, length outer_iterations
        SMALBE only: MPRGP steps performed in each outer iteration.
    n_hessian : int
        Number of multiplications by the Hessian ``A`` (SMALBE: by
        ``A + rho BE^T BE``), including those of the norm estimation.
    n_cg, n_expansion, n_proportioning : int
        Number of conjugate gradient, expansion and proportioning steps
        (Figure 6.6); their sum equals ``iterations``.
    mu : ndarray, shape (m,), or None
        SMALBE only: Lagrange multiplier of ``BE x = c``, with the sign
        convention of (6.2): ``A x - b + BE^T mu`` is the gradient of the
        Lagrangian, whose projected part is small at the solution.
    gradient_norms : ndarray
        MPRGP: ``||g^P(x^k)||`` for k = 0..iterations.
        SMALBE: ``||g^P(x^k, mu^k, rho_k)||`` at the end of each outer iteration.
    constraint_norms : ndarray
        SMALBE only: ``||BE x^k - c||`` at the end of each outer iteration.
    seconds : float
        Wall time of the call.
    penalty : float or None
        SMALBE only: final penalty parameter ``rho``.
    alpha : float or None
        Fixed expansion steplength used (SMALBE: the last one).
    """

    x: np.ndarray
    converged: bool
    reason: str
    iterations: int
    outer_iterations: int = 0
    inner_iterations: list[int] = field(default_factory=list)
    n_hessian: int = 0
    n_cg: int = 0
    n_expansion: int = 0
    n_proportioning: int = 0
    mu: np.ndarray | None = None
    gradient_norms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    constraint_norms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seconds: float = 0.0
    penalty: float | None = None
    alpha: float | None = None
