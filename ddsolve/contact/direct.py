"""Non-DD reference for (3.1): a primal-dual active set method with sparse direct solves.

Each step solves the equality-constrained problem of the current active set A
(u^1 = u^2 on the pairs in A) exactly, by merging the tied dofs
(:func:`ddsolve.multibody.direct.merge_matrix`) and one sparse factorization,
recovers lambda from stationarity, and updates

    A <- {k : lambda_k + c (B u)_k > 0}

(the semismooth Newton form of the complementarity condition, c = mean of
diag K). It stops when A repeats; the result satisfies the KKT conditions (5.5)
up to round-off.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse.linalg as spla

from ..multibody.direct import merge_matrix
from .problem import ContactProblem

log = logging.getLogger(__name__)


@dataclass
class ContactSolution:
    """Solution of (3.1) and the solver's diagnostics.

    Attributes
    ----------
    u : ndarray, shape (ndof,)
        Displacements, one value per body copy of the contact nodes.
    lam : ndarray, shape (n_c,)
        Contact multipliers (>= 0).
    active : ndarray of bool, shape (n_c,)
        Final active set (pairs in contact).
    converged : bool
    reason : str
    outer_iterations : int
        Active set updates (equality-constrained solves).
    inner_iterations : list of int
        Krylov / QP iterations of each outer iteration (empty for direct solves).
    pcg_iterations : int
        Iterations of the initial-guess PCG (active-set method only).
    seconds : float
    n_factorizations : int
    extra : dict
    """

    u: np.ndarray
    lam: np.ndarray
    active: np.ndarray
    converged: bool
    reason: str
    outer_iterations: int = 0
    inner_iterations: list[int] = field(default_factory=list)
    pcg_iterations: int = 0
    seconds: float = 0.0
    n_factorizations: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def total_iterations(self) -> int:
        return int(sum(self.inner_iterations))


def solve_face_direct(problem: ContactProblem, active: np.ndarray) -> np.ndarray:
    """u of the equality-constrained problem on the face ``active`` (sparse direct solve).

    Raises
    ------
    ValueError
        If ``active`` is empty while a body floats (singular problem).
    """
    T = merge_matrix(problem.sub, problem.gi, np.asarray(active, dtype=bool))
    A = (T.T @ problem.K @ T).tocsc()
    lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    if np.any(np.abs(lu.U.diagonal()) < 1e-12 * abs(A.diagonal()).max()):
        raise ValueError("the floating membrane is not tied to the clamped one: empty active set")
    return T @ lu.solve(T.T @ problem.f)


def solve_contact_direct(problem: ContactProblem, *, maxiter: int = 100) -> ContactSolution:
    """Primal-dual active set method with sparse direct face solves.

    Starts from full contact (every pair active). If an update empties the
    active set (a floating body would be free), the pair with the largest
    lambda_k + c (B u)_k is kept.

    Returns
    -------
    ContactSolution
        ``outer_iterations``: number of face solves; ``converged=False`` with a
        reason if the active set still changes after ``maxiter`` updates.
    """
    t0 = time.perf_counter()
    c = float(problem.K.diagonal().mean())
    active = np.ones(problem.n_contact, dtype=bool)
    seen: set[bytes] = set()
    converged, reason = False, f"active set still changing after {maxiter} updates"
    for it in range(1, maxiter + 1):
        u = solve_face_direct(problem, active)
        lam = problem.multipliers_from_residual(u, active)
        score = lam + c * problem.gap(u)
        scale = max(float(np.abs(lam).max()), c * float(np.abs(u).max()), 1e-300)
        new = score > 1e-12 * scale
        if not new.any():
            new[int(np.argmax(score))] = True
        if np.array_equal(new, active):
            converged, reason = True, f"active set repeated after {it} face solves"
            break
        key = np.packbits(new).tobytes()
        if key in seen:
            reason = "active set cycles"
            break
        seen.add(key)
        active = new
    log.info("contact direct (PDAS): %s", reason)
    return ContactSolution(u=u, lam=lam, active=active.copy(), converged=converged, reason=reason,
                           outer_iterations=it, seconds=time.perf_counter() - t0, n_factorizations=it)
