"""Model problem (3.1) in assembled form: stiffness, load, the contact operator and the KKT conditions (5.5).

The primal unknown u has one value per free node copy (``sub.ndof``; nodes on
Gamma_c have one copy per membrane). The non-penetration condition
u^2 - u^1 >= 0 on Gamma_c is B u <= 0 with

    (B u)_k = u^1(x_k) - u^2(x_k),   k = 0..n_c-1,

one row per matching node pair (``gi.pairs``: a on Omega^1, b on Omega^2), so
that the KKT conditions (5.5) read

    B u <= 0,   lambda >= 0,   lambda^T B u = 0,   K u - f + B^T lambda = 0.

lambda is the contact pressure (nodal force) that pushes Omega^2 up.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..dd.substructure import Substructures
from ..krylov.convergence import norm2
from ..multibody.interface import GlobalInterface


#: An iterative contact result (active set method, SMALBE) is accepted only if its KKT residual (5.5)
#: is at most min(max(KKT_ACCEPT_FACTOR rtol, KKT_ACCEPT_FLOOR), KKT_ACCEPT_CEILING): the active set
#: method's stopping rules bound the face-solve residuals, not the KKT conditions, and under extreme
#: coefficients the l2 rule of the face solves can stop with unresolved displacements. The ceiling:
#: at rtol 0.1 the sign tests (10 rtol) accepted a KKT residual of 0.48 with 1 of the 24 active pairs
#: (review of 2026-11-25); a residual above 1% is no solution at any rtol. SMALBE checks its
#: stationarity against 100 eps itself, without the ceiling: at rtol 0.5 it reported a KKT residual
#: of 0.74 converged (review of 2026-11-27), so the same rule applies to it.
KKT_ACCEPT_FACTOR = 100.0
KKT_ACCEPT_FLOOR = 1e-8
KKT_ACCEPT_CEILING = 1e-2


def kkt_limit(rtol: float) -> float:
    """min(max(KKT_ACCEPT_FACTOR rtol, KKT_ACCEPT_FLOOR), KKT_ACCEPT_CEILING): the largest KKT residual (5.5)
    of an accepted iterative contact solution."""
    return min(max(KKT_ACCEPT_FACTOR * float(rtol), KKT_ACCEPT_FLOOR), KKT_ACCEPT_CEILING)


def kkt_verdict(converged: bool, reason: str, kkt_max: float, rtol: float,
                weighted: float | None = None) -> tuple[bool, str]:
    """(converged, reason) of an iterative contact solve after the KKT acceptance rule (:func:`kkt_limit`):
    a solve that met its own rules with a larger KKT residual (or NaN) is not converged. Applied by
    :func:`~ddsolve.contact.active_set.solve_contact_active_set` and
    :func:`~ddsolve.contact.smalbe_dual.solve_contact_smalbe` themselves and, under mpiexec, to the
    distributed KKT residuals (:func:`ddsolve.contact.run.contact_fields`).

    ``weighted`` (optional): the penetration weighted by the stiffness
    (:meth:`ContactProblem.weighted_feasibility`), held to the same limit.
    """
    limit = kkt_limit(rtol)
    if not converged:
        return converged, reason
    rule = f"min(max({KKT_ACCEPT_FACTOR:g} rtol, {KKT_ACCEPT_FLOOR:g}), {KKT_ACCEPT_CEILING:g})"
    if not kkt_max <= limit:     # NaN fails the comparison
        return False, (f"not accepted: {reason.removeprefix('converged: ')}, but the KKT residual "
                       f"{kkt_max:.1e} > {limit:.1e} = {rule}")
    if weighted is not None and not weighted <= limit:
        return False, (f"not accepted: {reason.removeprefix('converged: ')}, but the penetration weighted by "
                       f"the stiffness (as a force) reads {weighted:.1e} > {limit:.1e} = {rule}: pairs in the "
                       f"wrong set under a coefficient jump")
    return converged, reason


def series_stiffness(d_first: np.ndarray, d_second: np.ndarray) -> np.ndarray:
    """w = 1 / (1/d_a + 1/d_b): the stiffness of a pair's two sides in series (the softer one decides;
    no overflow of d_a d_b at coefficients of 1e200; a zero side gives 0)."""
    with np.errstate(divide="ignore"):
        return 1.0 / (1.0 / np.asarray(d_first, dtype=float) + 1.0 / np.asarray(d_second, dtype=float))


def weighted_penetration(gap: np.ndarray, w: np.ndarray, force_scale: float) -> float:
    """max_i (B u)_i+ w_i / ||D u||_inf, the penetration in force units (:meth:`ContactProblem.weighted_feasibility`).

    Parameters
    ----------
    gap : ndarray, shape (n_c,)
        B u.
    w : ndarray, shape (n_c,)
        :func:`series_stiffness` of every pair.
    force_scale : float
        ||D u||_inf (NaN: NaN; 0: 0).
    """
    if math.isnan(force_scale) or np.isnan(gap).any():
        return math.nan
    if not force_scale > 0.0:
        return 0.0
    return max(float((np.maximum(gap, 0.0) * w).max(initial=0.0)), 0.0) / force_scale


@dataclass
class KKTResiduals:
    """Relative violations of the KKT conditions (5.5).

    Attributes
    ----------
    feasibility : float
        max(B u)_+ / ||u||_inf (penetration).
    dual_feasibility : float
        max(-lambda)_+ / ||lambda||_inf (negative contact pressure).
    complementarity : float
        |lambda^T B u| / (||lambda||_1 ||u||_inf).
    stationarity : float
        ||K u - f + B^T lambda||_2 / (||f||_2 + ||B^T lambda||_2): the force
        balance residual relative to the applied and contact forces it balances.
    """

    feasibility: float
    dual_feasibility: float
    complementarity: float
    stationarity: float

    @property
    def max(self) -> float:
        """The largest of the four (the ``kkt_residual`` of a result); NaN if any part is NaN."""
        parts = (self.feasibility, self.dual_feasibility, self.complementarity, self.stationarity)
        return float(np.max(parts))      # np.max propagates NaN wherever it is (builtin max drops a later one)

    def as_dict(self) -> dict[str, float]:
        return {"kkt_feasibility": self.feasibility, "kkt_dual_feasibility": self.dual_feasibility,
                "kkt_complementarity": self.complementarity, "kkt_stationarity": self.stationarity,
                "kkt_residual": self.max}


class ContactProblem:
    """Assembled data of (3.1) on a two-body :class:`Substructures`.

    Parameters
    ----------
    sub : Substructures
        Layout of :func:`ddsolve.scene.contact.two_membranes` (or any scene whose
        inter-body pairs are the contact nodes).
    gi : GlobalInterface, optional
        Its inter-body pairs (built if not given).

    Attributes
    ----------
    K : scipy.sparse.csr_matrix, shape (ndof, ndof)
        Block-diagonal (per body) stiffness; singular on the floating body.
    f : ndarray, shape (ndof,)
        Assembled load.
    B : scipy.sparse.csr_matrix, shape (n_c, ndof)
        Contact operator, (B u)_k = u^1 - u^2 at pair k.
    n_contact : int
        Number of contact multipliers n_c.
    y : ndarray, shape (n_c,)
        Position of each pair along Gamma_c.
    """

    def __init__(self, sub: Substructures, gi: GlobalInterface | None = None) -> None:
        self.sub = sub
        self.gi = gi if gi is not None else GlobalInterface(sub)
        self.K = sub.global_matrix().tocsr()
        self.f = sub.assemble_vector(sub.f_W)
        dofs = sub.dof_of_node[self.gi.pair_nodes]
        n = dofs.shape[0]
        self.n_contact = int(n)
        self.pair_dofs = dofs
        self.B = sp.csr_matrix((np.r_[np.ones(n), -np.ones(n)], (np.r_[np.arange(n), np.arange(n)],
                                                                 np.r_[dofs[:, 0], dofs[:, 1]])),
                               shape=(n, sub.ndof))
        self.y = sub.scene.coords[self.gi.pair_nodes[:, 0], 1]

    @property
    def ndof(self) -> int:
        return self.sub.ndof

    def energy(self, u: np.ndarray) -> float:
        """J(u) = 1/2 u^T K u - f^T u, the objective of (3.1) (inf or nan beyond the double range: a load
        of 1e300 gives J ~ 1e600; no RuntimeWarning is printed for it)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return float(0.5 * u @ (self.K @ u) - self.f @ u)

    def gap(self, u: np.ndarray) -> np.ndarray:
        """B u = u^1 - u^2 on Gamma_c, shape (n_c,); feasible where <= 0."""
        return self.B @ u

    def multipliers_from_residual(self, u: np.ndarray, active: np.ndarray) -> np.ndarray:
        """lambda from stationarity, given u: least-squares solution of B_A^T lambda = f - K u.

        Each active pair touches two dofs (one per body) that no other pair
        touches, so the least-squares value is the mean of the two residual
        entries, (f - K u)_a and -(f - K u)_b. Inactive entries are zero.
        """
        r = self.f - self.K @ u
        lam = 0.5 * (r[self.pair_dofs[:, 0]] - r[self.pair_dofs[:, 1]])
        return np.where(active, lam, 0.0)

    def stiffness(self) -> np.ndarray:
        """|diag K|, shape (ndof,)."""
        return np.abs(self.K.diagonal())

    def weighted_feasibility(self, u: np.ndarray) -> float:
        """Penetration in force units: max_i (B u)_i+ w_i / ||D u||_inf, D = diag(K), w_i = d_a d_b / (d_a + d_b)
        of the diagonal entries d_a, d_b of pair i's two dofs (two springs in series, :func:`series_stiffness`;
        :func:`weighted_penetration`). NaN for a u with NaN.

        The feasibility of :meth:`kkt` divides the penetration by ||u||_inf, so under coefficient jumps a
        penetration that is small against the soft bodies' displacements but large for a stiff
        subdomain (whose displacements are 1/rho as large) passes it: a review found SMALBE answers
        with 40-58% wrong multipliers and KKT residuals of 1e-5, another the active set method's plain
        sign test with lambda 110% off. Weighted by the local stiffness the same penetration reads as
        the force it implies; without jumps D is about constant and this equals the feasibility within
        a factor of about 2. (A complementarity weighted alike, lambda_i |(B u)_i| w_i, was tried and
        rejected: SMALBE's primal recovery leaves a stiff subdomain shifted rigidly by ~1e-6 of ||u||_inf,
        invisible in u and lambda, which that weight reads as an open pair under pressure.)
        """
        d = self.stiffness()
        w = series_stiffness(d[self.pair_dofs[:, 0]], d[self.pair_dofs[:, 1]])
        with np.errstate(invalid="ignore"):
            scale = float(np.max(np.abs(d * u), initial=0.0))
        return weighted_penetration(self.gap(u), w, scale)

    def stationarity_floor(self, u: np.ndarray, lam: np.ndarray) -> float:
        """The rounding level of the computed stationarity of :meth:`kkt`:
        eps ||(|K| |u| + |f| + |B^T| |lambda|)||_2 / (||f||_2 + ||B^T lambda||_2).

        An exact solution's computed residual reads about half of it (measured on the contact problem
        with rho 1 and checkerboards and body jumps of 1e-6 to 1e10: 0.4-0.5); at body jumps of 1e6 it
        exceeds 1e-8 (5e-8), where the direct solver's fixed tolerance rejected correct answers (a review).
        """
        contact = self.B.T @ lam
        scale = norm2(self.f) + norm2(contact)
        if not scale > 0.0:
            return 0.0
        size = abs(self.K) @ np.abs(u) + np.abs(self.f) + abs(self.B.T) @ np.abs(lam)
        return float(np.finfo(float).eps * norm2(size) / scale)

    def kkt(self, u: np.ndarray, lam: np.ndarray) -> KKTResiduals:
        """Relative KKT residuals (5.5) of a primal-dual pair.

        Parameters
        ----------
        u : ndarray, shape (ndof,)
        lam : ndarray, shape (n_c,)
        """
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(lam))):
            # a NaN lambda gave 0 for every residual (its maxima and sums compare False), which passed the
            # acceptance rule (a review); non-finite values are no solution
            return KKTResiduals(math.nan, math.nan, math.nan, math.nan)
        g = self.gap(u)
        u_inf = max(float(np.abs(u).max()), 1e-300)
        l_inf = float(np.abs(lam).max())
        l_one = float(np.abs(lam).sum())
        feas = max(float(g.max(initial=0.0)), 0.0) / u_inf + 0.0
        dual = max(float((-lam).max(initial=0.0)), 0.0) / l_inf + 0.0 if l_inf > 0 else 0.0
        comp = abs(float((lam / l_one) @ (g / u_inf))) if l_one > 0 else 0.0   # no under/overflow of l_one u_inf
        contact = self.B.T @ lam
        scale = norm2(self.f) + norm2(contact)                  # scaled norms: no under/overflow of squares
        stat = norm2(self.K @ u - self.f + contact) / scale if scale > 0.0 else 0.0
        return KKTResiduals(feas, dual, comp, stat)
