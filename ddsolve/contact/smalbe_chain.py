"""The chain of transforms of SMALBE on the FETI-DP dual (3.1) (Section 6.4): the formulation and its back-maps.

As PERMON prepares a FETI problem: :func:`dualize` (6.13) -> (6.14)-(6.15),
:func:`homogenize` (Lemma 6.4.1, (6.16)), :func:`enforce` the equality by projector
and penalty (6.17), :func:`solve_enforced` (SMALBE/MPRGP), :func:`map_back`.
Each step returns the transformed problem, which carries the back-map to the
previous one. The driver, its stopping rule, acceptance check and polish are in
:mod:`ddsolve.contact.smalbe_dual`.

Primal problem (6.13)
---------------------
Both membranes are split into N x N subdomains in FETI-DP fashion (all
subdomain vertices of a body primal, :class:`~ddsolve.multibody.fetifeti.FetiFetiSolver`).
On the space W~ of subdomain vectors with continuous primal values,

    min 1/2 u^T A~ u - f_W^T u   s.t.   B_E u = 0,   B_I u <= 0,

with B_E = B_loc (continuity inside each body, fully redundant at cross points)
and B_I = B_gl (one row per contact pair k, +1 on the Omega^1 copy and -1 on
the Omega^2 copy, so (B_I u)_k = u^1 - u^2 as in :class:`ContactProblem`).
B = [B_loc; B_gl] has n_lambda rows (161 for N = m = 4, Table 6.1). A~ is
singular on the floating body Omega^2; ker A~ = range R, R = constants on the
W entries of Omega^2 (one column).

Dual problem (6.14)-(6.15)
--------------------------
With the generalized inverse A~^+ (:attr:`PrimalConstrainedSolver.solve`, one
dof of Omega^2 pinned),

    F = B A~^+ B^T,  d~ = B A~^+ f_W,  G~ = R^T B^T  (1 x n_lambda),  e~ = R^T f_W,

    min theta(lambda) = 1/2 lambda^T F lambda - lambda^T d~
    s.t. lambda_I >= 0,  G~ lambda = e~.

G~ is 0 on the local rows and -1 on every contact row; e~ = integral of the
load on Omega^2 < 0 (the scene guarantees it). Orthonormalization of the single
row: T = 1 / ||G~|| = 1 / sqrt(n_c), G = T G~, e = T e~.

Homogenization (Lemma 6.4.1, (6.16))
------------------------------------
lambda~ = 0 on local rows and lambda~_I = -e~ / n_c > 0 (uniform contact
pressure carrying the load of Omega^2) satisfies G lambda~ = e and
lambda~_I >= 0. With lambda = lambda_full - lambda~:

    d = d~ - F lambda~ = B A~^+ (f_W - B^T lambda~)

(f_W - B^T lambda~ is in range A~ = (ker A~)^perp, so d does not depend on the
choice of generalized inverse), bounds lb_I = -lambda~_I, lb_E = -inf, and the
homogeneous equality G lambda = 0.

Problem solved (6.17)
---------------------
With Q = G^T G and P = I - Q,

    min 1/2 lambda^T (P F P + rho_bar Q) lambda - lambda^T P d
    s.t. lambda_I >= -lambda~_I,  G lambda = 0,

which has the same solution as (6.16) (on ker G, P lambda = lambda). (Read
with the homogenized data: the printed (6.17) keeps the bounds and the right
hand side of (6.15).) P F P + rho_bar Q is symmetric positive definite; F is
applied with one A~^+ solve (the factorizations of ``solver`` are reused,
nothing is refactored per iteration), P and Q with the dense row G.

Primal recovery
---------------
SMALBE returns lambda with ||G lambda|| <= eps ||b|| only. The raw
lambda + lambda~ is not balanced: R^T (f_W - B^T (lambda + lambda~)) =
-||G~|| G lambda != 0, and A~^+ (pinned generalized inverse) would dump this
force imbalance onto the pinned dof. The recovery therefore uses the balanced
multiplier of (6.17), whose F part only sees P lambda,

    lambda_bal = P lambda + lambda~       (G~ lambda_bal = e~ exactly),
    u~ = A~^+ (f_W - B^T lambda_bal) + R alpha,

an exact solution of A~ u~ = f_W - B^T lambda_bal. Since B A~^+ B^T P lambda -
d = -B u0 differs from the SMALBE gradient only by a multiple of G^T = B R / ||G~||,
the rigid amplitude alpha can make B u~ = -g: jumps and gaps are bounded by
the final projected gradient. alpha minimizes ||B_A u~|| over the active pairs
A (with one floating body B_A R = -1: alpha = mean over A of (B u0)_k).
u~ is mapped to the assembled dofs by the delta-weighted average
:meth:`Substructures.average`.

Active set and returned multipliers: A = the contact rows that are off their
bound in the SMALBE iterate (lambda_k > -lambda~_k; MPRGP keeps the others
exactly at the bound) and have lambda_bal_k > 0; ``lam = lambda_bal`` on A and
0 elsewhere. P shifts every contact entry by the same
kappa = -G_c (G lambda), |kappa| = |G lambda| / sqrt(n_c) (``extra["equality_defect"]``
is G lambda), so zeroing the inactive entries is a force error of at most
(n_c - n_A) |kappa| <= (||G lambda|| / ||e||) net, which the stopping rule keeps
below eps net.
Alternatives that keep the multiplier exactly balanced *and* sign-feasible
(scaling the contact part by -e~ / sum_k lambda_k, or shifting only the active
entries) perturb P lambda by a self-balanced O(||G lambda||) vector, which F
amplifies by ~||P F P|| into interface jumps; on the tested grids they gave
4-50 times larger stationarity residuals.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..dd.projection import Projection
from ..krylov.convergence import norm2
from ..multibody.fetifeti import FetiFetiSolver
from ..qp import estimate_norm, smalbe
from ..qp.result import QPResult
from .problem import ContactProblem

__all__ = ["NORM_SAFETY", "DualProblem", "dualize", "HomogeneousProblem", "homogenize", "EnforcedProblem",
           "enforce", "solve_enforced", "RecoveredSolution", "map_back"]

#: Safety factor on the Lanczos estimate of ||P F P|| passed as ``norm_A`` to SMALBE.
NORM_SAFETY = 1.0 + 1e-3


# ----------------------------------------------------------------------------- the chain of transforms
# As PERMON prepares a FETI problem: dualize -> homogenize (Lemma 6.4.1) -> enforce the equality by
# projector and penalty (6.17) -> solve (SMALBE/MPRGP) -> map back. Each step is a small function
# returning the transformed problem, which carries the back-map to the previous one.

@dataclass
class DualProblem:
    """The FETI-DP dual (6.14)-(6.15) of (6.13), and the primal recovery (its back-map).

    Attributes
    ----------
    solver : FetiFetiSolver
        A~^+ (``solver.primal_solver``), B_loc and R.
    B, BT : sparse matrix, shapes (n_lambda, n_W) and (n_W, n_lambda)
        [B_loc; B_gl] and its transpose.
    B_contact : sparse matrix, shape (n_c, n_W)
        B_gl = B_I, one row per contact pair.
    n_local, n_contact : int
        Row counts of B_loc and B_gl (n_lambda = n_local + n_contact).
    kernel : ndarray, shape (n_W,)
        R: the constants on the W entries of the floating body Omega^2.
    G : ndarray, shape (n_lambda,)
        The orthonormalized row G = T G~, G~ = R^T B^T, T = 1 / ||G~|| (||G|| = 1).
    e : float
        e = T e~, e~ = R^T f_W (< 0).
    e_tilde : float
    net_load : float
        -e~: the load on Omega^2 that sum(lambda) must carry (> 0).
    n_F : list of int
        One-element counter of products with F.
    F_scale : float
        The coefficient scale of F = B A~^+ B^T: 1 / min rho (F ~ 1/rho; 1 for rho = 1). Converts
        the dual's displacements into forces (``||b|| / F_scale``) and sets the defaults of the
        absolute SMALBE parameters (:func:`ddsolve.contact.smalbe_dual.solve_contact_smalbe`), so
        that they follow rho -> s rho.
    """

    problem: ContactProblem
    solver: FetiFetiSolver
    B: sp.csr_matrix
    BT: sp.csr_matrix
    B_contact: sp.csr_matrix
    n_local: int
    n_contact: int
    kernel: np.ndarray
    G: np.ndarray
    e: float
    e_tilde: float
    net_load: float
    n_F: list = field(default_factory=lambda: [0])
    F_scale: float = 1.0

    @property
    def n(self) -> int:
        """n_lambda."""
        return self.n_local + self.n_contact

    def F(self, v: np.ndarray) -> np.ndarray:
        """F v = B A~^+ B^T v, shape (n_lambda,)."""
        self.n_F[0] += 1
        return self.B @ self.solver.primal_solver.solve(self.BT @ v)

    def primal_solve(self, lam: np.ndarray) -> np.ndarray:
        """A~^+ (f_W - B^T lam), shape (n_lambda,) -> (n_W,)."""
        return self.solver.primal_solver.solve(self.problem.sub.f_W - self.BT @ lam)

    def back(self, lam_balanced: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Primal recovery from a balanced multiplier (module docstring, "Primal recovery").

        u~ = A~^+ (f_W - B^T lambda_bal) + R alpha, alpha minimizing ||B_A u~|| over the active
        pairs (all pairs when none is active).

        Returns
        -------
        (u_W, u, alpha) : ndarray (n_W,), ndarray (ndof,), float
        """
        u0 = self.primal_solve(lam_balanced)
        Bu0 = self.B_contact @ u0
        BR = np.asarray(self.B_contact @ self.kernel).ravel()         # -1 on every contact row
        rows = active if active.any() else np.ones(self.n_contact, dtype=bool)
        alpha = -float(BR[rows] @ Bu0[rows]) / float(BR[rows] @ BR[rows])
        u_W = u0 + alpha * self.kernel
        return u_W, self.problem.sub.average(u_W), alpha


def dualize(problem: ContactProblem, solver: FetiFetiSolver) -> DualProblem | str:
    """(6.13) -> (6.14)-(6.15): B = [B_loc; B_gl], G~ = R^T B^T, e~ = R^T f_W, orthonormalized.

    Returns the reason as a string for data that (6.17) cannot handle.
    """
    if solver.floating.size != 1:
        return f"expected exactly one floating body (Omega^2), found {solver.floating.size}"
    sub = problem.sub
    B_contact, _ = problem.gi.operators(None)
    B = sp.vstack([solver.B_loc, B_contact]).tocsr()
    kernel = solver.R.toarray().ravel()                       # (n_W,) constants on Omega^2
    G_tilde = np.asarray(B @ kernel).ravel()                  # (n_lambda,)
    e_tilde = float(kernel @ sub.f_W)
    norm_G_tilde = norm2(G_tilde)
    if norm_G_tilde == 0.0 or not e_tilde < 0.0:
        return (f"the floating body is not pressed onto the contact interface "
                f"(R^T f_W = {e_tilde:.3g}, ||G~|| = {norm_G_tilde:.3g})")
    rho = np.asarray(sub.rho, dtype=float)
    rho_min = float(rho.min()) if rho.size else 1.0
    F_scale = 1.0 / rho_min if rho_min > 0.0 and math.isfinite(1.0 / rho_min) else 1.0
    return DualProblem(problem=problem, solver=solver, B=B, BT=B.T.tocsr(), B_contact=B_contact,
                       n_local=solver.B_loc.shape[0], n_contact=B_contact.shape[0], kernel=kernel,
                       G=G_tilde / norm_G_tilde, e=e_tilde / norm_G_tilde, e_tilde=e_tilde, net_load=-e_tilde,
                       F_scale=F_scale)


@dataclass
class HomogeneousProblem:
    """(6.16): lambda = lambda_full - lambda~ with G lambda = 0 (Lemma 6.4.1); back-map lambda + lambda~.

    Attributes
    ----------
    dual : DualProblem
    lambda_tilde : ndarray, shape (n_lambda,)
        0 on local rows, the uniform pressure -e~ / n_c on contact rows (G lambda~ = e).
    d : ndarray, shape (n_lambda,)
        d~ - F lambda~ = B A~^+ (f_W - B^T lambda~).
    lower : ndarray, shape (n_lambda,)
        Bounds: -inf on local rows, -lambda~ on contact rows.
    """

    dual: DualProblem
    lambda_tilde: np.ndarray
    d: np.ndarray
    lower: np.ndarray

    def back(self, lam: np.ndarray) -> np.ndarray:
        """lambda_full = lambda + lambda~."""
        return lam + self.lambda_tilde


def homogenize(dual: DualProblem) -> HomogeneousProblem | str:
    """(6.15) -> (6.16) by Lemma 6.4.1 (uniform contact pressure carrying the load of Omega^2)."""
    n_local, n = dual.n_local, dual.n
    lambda_tilde = np.zeros(n)
    lambda_tilde[n_local:] = -dual.e_tilde / dual.n_contact
    if not np.isclose(dual.G @ lambda_tilde, dual.e, rtol=1e-12, atol=0.0):
        return "G~ is not -1 on the contact rows and 0 on the local rows"
    d = dual.B @ dual.primal_solve(lambda_tilde)
    lower = np.full(n, -np.inf)
    lower[n_local:] = -lambda_tilde[n_local:]
    return HomogeneousProblem(dual=dual, lambda_tilde=lambda_tilde, d=d, lower=lower)


@dataclass
class EnforcedProblem:
    """(6.17): min 1/2 l^T (P F P + rho_bar Q) l - l^T P d  s.t.  l_I >= lower_I, G l = 0.

    Back-map: the balanced multiplier P lambda + lambda~ (G~ of it is e~ exactly).

    Attributes
    ----------
    homogeneous : HomogeneousProblem
    projection : Projection
        P = I - G^T G (orthonormal row; Q = I - P).
    hessian : LinearOperator, shape (n_lambda, n_lambda)
        P F P + rho_bar Q.
    equality : sparse matrix, shape (1, n_lambda)
        The row G of G lambda = 0.
    b : ndarray, shape (n_lambda,)
        P d.
    norm_b, norm_PFP, rho_bar : float
    n_norm_estimate : int
        Products with P F P used by the norm estimate.
    """

    homogeneous: HomogeneousProblem
    projection: Projection
    hessian: spla.LinearOperator
    equality: sp.csr_matrix
    b: np.ndarray
    norm_b: float
    norm_PFP: float
    n_norm_estimate: int
    rho_bar: float

    def back(self, lam: np.ndarray) -> np.ndarray:
        """lambda_bal = P lambda + lambda~."""
        return self.homogeneous.back(self.projection.apply(lam))


def enforce(homogeneous: HomogeneousProblem, rho_bar: float | None) -> EnforcedProblem | str:
    """(6.16) -> (6.17): the equality G lambda = 0 by the projector P and the penalty rho_bar Q.

    ||P F P|| is estimated (:func:`ddsolve.qp.estimate_norm`) for SMALBE's steplength;
    ``rho_bar=None`` takes it as rho_bar.
    """
    dual = homogeneous.dual
    n = dual.n
    G = dual.G
    P = Projection(G, orthonormal=True)
    b = P.apply(homogeneous.d)
    PFP = spla.LinearOperator((n, n), matvec=lambda v: P.apply(dual.F(P.apply(np.ravel(v)))), dtype=np.float64)
    try:
        with np.errstate(invalid="ignore", over="ignore"):
            norm_PFP, n_est = estimate_norm(PFP)
    except FloatingPointError:            # F overflowed (an extreme but accepted rho): a breakdown, reported
        return "numerical breakdown in smalbe: the dual operator P F P returned non-finite values"
    if rho_bar is None:
        rho_bar = norm_PFP
    elif isinstance(rho_bar, bool) or not (isinstance(rho_bar, numbers.Real) and math.isfinite(rho_bar)
                                           and rho_bar > 0.0):
        return f"rho_bar must be a positive number, got {rho_bar!r}"
    rho_bar = float(rho_bar)

    def hessian(v: np.ndarray) -> np.ndarray:
        """(P F P + rho_bar Q) v of (6.17)."""
        v = np.ravel(v)
        Gv = G @ v
        return P.apply(dual.F(v - G * Gv)) + rho_bar * G * Gv

    return EnforcedProblem(homogeneous=homogeneous, projection=P,
                           hessian=spla.LinearOperator((n, n), matvec=hessian, rmatvec=hessian, dtype=np.float64),
                           equality=sp.csr_matrix(G[None, :]), b=b, norm_b=norm2(b),
                           norm_PFP=norm_PFP, n_norm_estimate=n_est, rho_bar=rho_bar)


def solve_enforced(enforced: EnforcedProblem, *, eps: float, M: float, rho0: float, Gamma: float,
                   maxiter: int | None, max_outer: int, equality_rule: str = "min", halfstep: bool = True
                   ) -> tuple[QPResult, float | None]:
    """SMALBE (Figure 6.7) with MPRGP inner solves (Figure 6.6) on (6.17).

    Stopping rule ||g^P|| <= eps ||b|| and ||G lambda|| <= eps min(||b|| / F_scale, ||e||)
    (:mod:`ddsolve.contact.smalbe_dual`, "Stopping rule"; ``equality_rule="min"``; ||b|| / F_scale
    is the displacement ||b|| in force units, ||b|| for rho = 1) or ||G lambda|| <= eps ||b||
    (``"section-6.4"``, as printed); steplength from ``norm_A = NORM_SAFETY max(||P F P||, rho_bar)``;
    ``halfstep`` of MPRGP's expansion steps (:func:`ddsolve.qp.mprgp.mprgp`; False: Figure 6.6 as printed).

    Returns
    -------
    (result, tol_equality)

    Raises
    ------
    ValueError
        Invalid SMALBE parameters.
    """
    e = enforced.homogeneous.dual.e
    b_force = enforced.norm_b / enforced.homogeneous.dual.F_scale
    tol_eq = eps * min(b_force, abs(e)) if isinstance(eps, numbers.Real) and math.isfinite(eps) else 0.0
    tol_eq = tol_eq if tol_eq > 0.0 else None              # invalid eps: smalbe reports it; b = 0: its rule
    if equality_rule == "section-6.4":
        tol_eq = None                                      # smalbe's own rule: eps ||b||
    result = smalbe(enforced.hessian, enforced.b, enforced.homogeneous.lower, enforced.equality, None, None,
                    M=M, rho0=rho0, Gamma=Gamma, eps=eps, maxiter=maxiter,
                    norm_A=NORM_SAFETY * max(enforced.norm_PFP, enforced.rho_bar), norm_BE=1.0,
                    feas_tol=tol_eq, max_outer=max_outer, halfstep=halfstep)
    return result, tol_eq


@dataclass
class RecoveredSolution:
    """What the chain maps back: the balanced multiplier, the contact multipliers and u."""

    lambda_balanced: np.ndarray     # (n_lambda,)
    lam_contact: np.ndarray         # (n_c,) >= 0, 0 off the active set
    active: np.ndarray              # (n_c,) bool
    u_W: np.ndarray                 # (n_W,)
    u: np.ndarray                   # (ndof,)
    rigid_alpha: float
    equality_defect: float          # G lambda


def map_back(enforced: EnforcedProblem, lam: np.ndarray) -> RecoveredSolution:
    """SMALBE's lambda of (6.17) -> (u, lambda) of (6.13) (module docstring, "Primal recovery").

    Active set: the contact rows off their bound in the SMALBE iterate with positive balanced
    multiplier.
    """
    homogeneous = enforced.homogeneous
    dual = homogeneous.dual
    n_local = dual.n_local
    lam_bal = enforced.back(lam)
    free = lam[n_local:] > homogeneous.lower[n_local:]           # contact rows off their bound in SMALBE
    active = free & (lam_bal[n_local:] > 0.0)
    lam_contact = np.where(active, lam_bal[n_local:], 0.0)
    u_W, u, alpha = dual.back(lam_bal, active)
    return RecoveredSolution(lambda_balanced=lam_bal, lam_contact=lam_contact, active=active, u_W=u_W, u=u,
                             rigid_alpha=alpha, equality_defect=float(dual.G @ lam))
