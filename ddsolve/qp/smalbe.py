"""SMALBE: Semi-Monotonic Augmented Lagrangians for Bound and Equality constraints.

Solves the bound and equality constrained convex quadratic program (6.1) of Lee's thesis,

.. math::

    \\min f(x) = \\tfrac12 x^T A x - b^T x \\quad \\text{s.t.} \\quad x \\ge l,\\; B_E x = c,

with the algorithm of Figure 6.7 (Section 6.3; Dostál [13], [14, Chapter 6]). The equality
constraints are treated by the augmented Lagrangian (6.2),

.. math::

    L(x, \\mu, \\rho) = f(x) + (B_E x - c)^T \\mu + \\tfrac{\\rho}{2} \\|B_E x - c\\|^2,

whose gradient (6.3) is ``g(x, mu, rho) = A x - b + B_E^T (mu + rho (B_E x - c))``; the bound
constrained inner problems ``min_{x >= l} L(x, mu^k, rho_k)`` (Hessian
``A + rho_k B_E^T B_E``) are solved inexactly by MPRGP (Figure 6.6,
:mod:`ddsolve.qp.mprgp`), warm started from the previous outer iterate.

Outer iteration k (Figure 6.7):

1. (inner, adaptive precision control) find ``x^k >= l`` with
   ``||g^P(x^k, mu^k, rho_k)|| <= min(M ||B_E x^k - c||, eta)``, or stop early when the
   outer stopping rule below already holds;
2. stop if ``||g^P(x^k, mu^k, rho_k)|| <= eps ||b||`` and ``||B_E x^k - c|| <= eps ||b||``
   (the stopping criterion of Section 6.4; ``feas_tol`` replaces the second bound, e.g.
   by a smaller one relative to the size of ``c`` or of what the constraint carries);
3. ``mu^{k+1} = mu^k + rho_k (B_E x^k - c)``;
4. if ``k > 0`` and ``L(x^k, mu^k, rho_k) < L(x^{k-1}, mu^{k-1}, rho_{k-1})
   + rho_k/2 ||B_E x^k - c||^2`` then ``rho_{k+1} = beta rho_k`` else ``rho_{k+1} = rho_k``.

At convergence the returned multiplier is ``mu = mu^k + rho_k (B_E x^k - c)``, so that
``A x - b + B_E^T mu = g(x^k, mu^k, rho_k)`` has a small projected part (KKT conditions of
(6.1) with the sign convention of (6.2)).

Scale invariance: the iteration runs on the problem rescaled by powers of two
(:mod:`ddsolve.qp.scaling`; ``rho`` and ``mu`` rescaled with ``A`` and ``b``), which
is exact: the same numbers as the unscaled iteration wherever that one does not over-
or underflow, and representable curvatures, norms and tolerances (``eps ||b||``) for
data anywhere in the double range. The parameters are absolute: ``rho0`` in the units of
``A / ||BE||^2``, ``M`` in those of ``A``, ``eta`` and ``atol`` in those of ``b``, ``feas_tol``
in those of ``x`` (``BE x - c``); the default ``feas_tol = eps ||b||`` of Section 6.4
compares ``||BE x - c||`` with a quantity in the units of ``b``. Scaling ``A`` by ``s`` and
``b`` by ``t`` gives the same iterations (and ``x`` scaled by ``t/s``) when ``rho0`` and ``M``
are scaled by ``s`` and ``feas_tol`` by ``t/s``; scaling ``b`` alone needs nothing.
"""
from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np
from scipy.sparse.linalg import LinearOperator

from ..errors import InputError, check_tolerance
from ..krylov.convergence import norm2
from .mprgp import (ALPHA_FACTOR, _mprgp_core, _start_vector, as_operator, as_vector, checked_norm,
                    check_count, check_positive)
from .result import QPResult
from .scaling import QPScaling

log = logging.getLogger(__name__)


def smalbe(A: Any, b: Any, lb: Any, BE: Any, c: Any = None, x0: Any = None, *,
           M: float = 1.0, rho0: float = 30.0, eta: float | None = None, beta: float = 10.0,
           Gamma: float = 1.0, eps: float = 1e-5, atol: float = 0.0, maxiter: int | None = None,
           max_outer: int = 100, norm_A: float | None = None, norm_BE: float | None = None,
           mu0: Any = None, halfstep: bool = True, feas_tol: float | None = None) -> QPResult:
    """Solve ``min 1/2 x^T A x - b^T x  s.t.  x >= lb, BE x = c`` by SMALBE (Figure 6.7).

    See the module docstring for the algorithm.

    Parameters
    ----------
    A : ndarray, sparse matrix or LinearOperator, shape (n, n)
        Symmetric positive semidefinite Hessian, positive definite on ``ker(BE)`` (e.g.
        ``F`` or the already penalised ``P F P + rho Q`` of (6.17)).
    b : array_like, shape (n,)
        Linear term.
    lb : array_like, shape (n,) or scalar
        Lower bounds; ``-inf`` entries are not bound constrained.
    BE : ndarray, sparse matrix or LinearOperator, shape (m, n)
        Equality constraint matrix (``G`` of (6.15)-(6.17)).
    c : array_like, shape (m,), optional
        Equality right-hand side, ``c in Im(BE)`` (default 0).
    x0 : array_like, shape (n,), optional
        Start vector (default ``max(0, lb)``), projected onto ``{x >= lb}``.
    M : float
        Precision control constant ``M > 0`` of the inner stopping rule (Section 6.4: 1).
    rho0 : float
        Initial penalty ``rho_0 > 0`` (Section 6.4: 30). The rate of the multiplier update
        depends on ``rho`` relative to the curvature of ``A`` on ``ker(BE)``; when the inner
        problems are solved accurately the Lagrangian test of step 4 rarely fires, so a
        ``rho0`` far below ``||A|| / ||BE||^2`` can cost many outer iterations.
    eta : float, optional
        Inner tolerance cap ``eta > 0``; default ``0.1 ||b||`` (1.0 if ``b = 0``). Not
        stated in the thesis; Theorem 6.1.1 asks ``||b|| >= eta > 0``.
    beta : float
        Penalty growth factor ``beta > 1`` (Figure 6.7 step 4); default 10 (not stated in
        the thesis).
    Gamma : float
        MPRGP proportioning parameter (Section 6.4: 1).
    eps : float
        Relative tolerance of the outer stopping rule of Section 6.4, in (0, 1),
        ``||g^P|| <= eps ||b||`` and ``||BE x - c|| <= eps ||b||`` (Section 6.4: 1e-5).
    atol : float
        Absolute floor of both outer tolerances: ``max(eps ||b||, atol)`` (for ``b = 0``).
    maxiter : int, optional
        Maximum total number of MPRGP steps over all outer iterations
        (default ``max(200, 20 n)``).
    max_outer : int
        Maximum number of outer iterations.
    norm_A, norm_BE : float, optional
        ``||A||_2`` and ``||BE||_2``, estimated by seeded Lanczos
        (:func:`~ddsolve.qp.norm.estimate_norm`) when not given.
        The MPRGP steplength for penalty ``rho`` is ``1.9 / (||A|| + rho ||BE||^2)``, an
        admissible value since ``||A + rho BE^T BE|| <= ||A|| + rho ||BE||^2``.
    mu0 : array_like, shape (m,), optional
        Initial multiplier ``mu^0`` (default 0).
    halfstep : bool
        Passed to MPRGP (feasible half step before expansion steps).
    feas_tol : float, optional
        Absolute tolerance of the equality part of the outer stopping rule,
        ``||BE x - c|| <= feas_tol`` (default the thesis's ``max(eps ||b||, atol)``). A
        caller whose equality carries a quantity much smaller than ``||b||`` (the net
        contact force of :func:`ddsolve.contact.smalbe_dual.solve_contact_smalbe`)
        passes a smaller value.

    Returns
    -------
    QPResult
        ``x``, ``mu``, ``converged``, ``reason``, ``iterations`` (total MPRGP steps),
        ``outer_iterations``, ``inner_iterations`` (steps per outer iteration), step
        counters, ``n_hessian`` (multiplications by ``A + rho BE^T BE``, plus the ``A``
        multiplications of the norm estimate), ``gradient_norms`` and
        ``constraint_norms`` per outer iteration, ``penalty`` (final ``rho``).

    Raises
    ------
    ValueError
        (:class:`~ddsolve.errors.InputError`) on shape mismatch, non-finite data or invalid
        parameters (``M, rho0, eta, Gamma <= 0``, ``eps`` outside (0, 1), ``beta <= 1``, ...).
    """
    t0 = time.perf_counter()
    n = int(np.asarray(b).size)
    if n == 0:
        raise InputError("b", "must be a non-empty vector")
    b = as_vector(b, n, "b")
    opA = as_operator(A, (n, n), "A")
    opB = as_operator(BE, (-1, n), "BE")
    try:                                   # SMALBE needs BE^T (a LinearOperator may define matvec only)
        opB.rmatvec(np.zeros(opB.shape[0]))
    except NotImplementedError:
        raise InputError("BE", "the operator has no transpose (rmatvec): SMALBE applies BE^T") from None
    m = opB.shape[0]
    if m == 0:
        raise InputError("BE", "must have at least one row")
    lb = as_vector(lb, n, "lb", allow_scalar=True, allow_neg_inf=True)
    c = np.zeros(m) if c is None else as_vector(c, m, "c")
    mu = np.zeros(m) if mu0 is None else as_vector(mu0, m, "mu0")
    M = check_positive("M", M)
    rho = check_positive("rho0", rho0)
    beta = check_positive("beta", beta)
    if beta <= 1.0:
        raise InputError("beta", f"must be > 1, got {beta!r}")
    Gamma = check_positive("Gamma", Gamma)
    eps = check_tolerance("eps", eps)     # eps >= 1 stopped at x0 "converged" (2: x 15% off; a review)
    atol = check_positive("atol", atol, strict=False)
    max_outer = check_count("max_outer", max_outer, 1)
    maxiter = max(200, 20 * n) if maxiter is None else check_count("maxiter", maxiter)
    norm_b = norm2(b)
    if norm_b == 0.0 and atol == 0.0:     # b = 0: the rule max(eps ||b||, atol) = 0 is never met (a review)
        raise InputError("atol", "b = 0 makes the stopping rule max(eps ||b||, atol) zero, which is never met: "
                                 "give atol > 0")
    if eta is not None:
        eta = check_positive("eta", eta)
    if feas_tol is not None:
        feas_tol = check_positive("feas_tol", feas_tol)
    x = _start_vector(x0, lb, n)

    n_hessian = 0
    if norm_A is None:
        norm_A, k = checked_norm(opA, "A")
        n_hessian += k
    else:
        norm_A = check_positive("norm_A", norm_A)
    if norm_BE is None:
        btb = LinearOperator((n, n), matvec=lambda v: opB.rmatvec(opB.matvec(v)), dtype=np.float64)
        norm_btb, _ = checked_norm(btb, "BE")
        norm_BE = math.sqrt(norm_btb)
    else:
        norm_BE = check_positive("norm_BE", norm_BE)
    if norm_A + norm_BE == 0.0:
        raise InputError("A", "A and BE are both zero")

    # the problem in the units of :mod:`ddsolve.qp.scaling` (exact powers of two): A = 2^a A',
    # b = 2^e b', x, lb, c, BE x - c = 2^(e-a) (.)', mu = 2^e mu', rho = 2^a rho'
    sc = QPScaling.of(norm_A, b, x, lb, c)
    up = QPScaling.up
    lb_user = lb
    b, lb, c, x, mu = up(b, -sc.e), up(lb, -sc.x), up(c, -sc.x), up(x, -sc.x), up(mu, -sc.e)
    norm_b = norm2(b)
    if eta is None:
        eta = 0.1 * norm_b if norm_b > 0.0 else up(1.0, -sc.e)
    else:
        eta = up(eta, -sc.e)
    atol = up(atol, -sc.e)
    norm_A = up(norm_A, -sc.a)
    rho = up(rho, -sc.a)
    M = up(M, -sc.a)                                 # ||g^P|| <= M ||BE x - c||: M has the units of A

    def Bmul(v: np.ndarray) -> np.ndarray:
        return np.asarray(opB.matvec(v), dtype=np.float64).ravel()

    def BTmul(w: np.ndarray) -> np.ndarray:
        return np.asarray(opB.rmatvec(w), dtype=np.float64).ravel()

    def Amul(v: np.ndarray) -> np.ndarray:
        """A' v = 2^-a A v."""
        out = np.asarray(opA.matvec(v), dtype=np.float64).ravel()
        return up(out, -sc.a) if sc.a else out

    penalty = [rho]                                  # mutable, read by H at call time

    def Hmul(v: np.ndarray) -> np.ndarray:
        """Hessian of L(., mu, rho): (A + rho BE^T BE) v."""
        return Amul(v) + penalty[0] * BTmul(Bmul(v))

    tol_outer = max(eps * norm_b, atol)
    rule = "eps ||b||" if eps * norm_b >= atol else "atol"
    # ||BE x - c|| <= tol_feas (in the units of x: the user's tol_outer is 2^e tol_outer' = 2^(e-a) tol_feas')
    tol_feas = up(tol_outer, sc.a) if feas_tol is None else up(feas_tol, -sc.x)

    def gu(value: float) -> float:
        """A gradient norm in the caller's units (messages, histories)."""
        return up(value, sc.e)

    def xu(value: float) -> float:
        """A norm of BE x - c in the caller's units."""
        return up(value, sc.x)

    BTc = BTmul(c)

    # gradient of L(x, mu, rho) (6.3): A x - b + BE^T (mu + rho (BE x - c))
    r = Bmul(x) - c
    g = Amul(x) - b + BTmul(mu + rho * r)
    n_hessian += 1

    def inner_stop(xk: np.ndarray, gp_norm: float) -> str | None:
        feas = norm2(Bmul(xk) - c)
        if gp_norm <= tol_outer and feas <= tol_feas:
            return f"outer rule met: ||g^P|| = {gu(gp_norm):.3e}, ||BE x - c|| = {xu(feas):.3e}"
        bound = min(M * feas, eta)
        if gp_norm <= bound:
            return f"||g^P|| = {gu(gp_norm):.3e} <= min(M ||BE x - c||, eta) = {gu(bound):.3e}"
        return None

    inner: list[int] = []
    gp_hist: list[float] = []
    feas_hist: list[float] = []
    counts = {"cg": 0, "exp": 0, "prop": 0}
    total = 0
    L_prev = None
    converged = False
    reason = ""
    alpha = ALPHA_FACTOR / (norm_A + rho * norm_BE ** 2)
    gp_norm = feas = math.nan
    for k in range(max_outer):
        alpha = ALPHA_FACTOR / (norm_A + rho * norm_BE ** 2)
        # inner problem: min_{x >= lb} 1/2 x^T H x - bt^T x, bt = b - BE^T mu + rho BE^T c
        bt = b - BTmul(mu) + rho * BTc
        remaining = maxiter - total
        core = _mprgp_core(Hmul, bt, lb, x, g, alpha=alpha, Gamma=Gamma, stop=inner_stop,
                           maxiter=remaining, halfstep=halfstep, g_exp=sc.e,
                           confirm=lambda msg: msg.startswith("outer rule met"))   # only the stop that ends it
        x, g = core.x, core.g
        total += core.steps
        inner.append(core.steps)
        n_hessian += core.n_matvec
        counts["cg"] += core.n_cg
        counts["exp"] += core.n_expansion
        counts["prop"] += core.n_proportioning
        r = Bmul(x) - c
        feas = norm2(r)
        gp_norm = core.gp_norms[-1]
        gp_hist.append(gu(gp_norm))
        feas_hist.append(xu(feas))
        log.debug("SMALBE outer %d: rho = %.3g, %d MPRGP steps, ||g^P|| = %.3e, ||BE x - c|| = %.3e",
                  k, up(rho, sc.a), core.steps, gu(gp_norm), xu(feas))
        if not core.converged:
            if core.steps >= remaining:
                reason = (f"maxiter {maxiter} (total MPRGP steps) reached in outer iteration {k}: "
                          f"||g^P|| = {gu(gp_norm):.3e}, ||BE x - c|| = {xu(feas):.3e}")
            else:
                reason = f"inner MPRGP failed in outer iteration {k}: {core.reason}"
            mu = mu + rho * r
            break
        # Lagrangian L(x^k, mu^k, rho_k) from the inner gradient: L = 1/2 x^T (g - bt) + const
        L_k = 0.5 * float(x @ (g - bt)) - float(c @ mu) + 0.5 * rho * float(c @ c)
        # multiplier update (step 3); at convergence this is the KKT multiplier
        mu = mu + rho * r
        if gp_norm <= tol_outer and feas <= tol_feas:
            converged = True
            if xu(tol_feas) == gu(tol_outer):
                reason = (f"converged: ||g^P|| = {gu(gp_norm):.3e} and ||BE x - c|| = {xu(feas):.3e} "
                          f"<= {rule} = {gu(tol_outer):.3e}")
            else:
                reason = (f"converged: ||g^P|| = {gu(gp_norm):.3e} <= {rule} = {gu(tol_outer):.3e} and "
                          f"||BE x - c|| = {xu(feas):.3e} <= {xu(tol_feas):.3e}")
            break
        # penalty update (step 4)
        rho_new = rho
        if L_prev is not None and L_k < L_prev + 0.5 * rho * feas ** 2:
            rho_new = beta * rho
        L_prev = L_k
        # gradient for (mu^{k+1}, rho_{k+1}) without an A multiplication:
        # g_new = g + BE^T (mu^{k+1} - mu^k) + (rho_{k+1} - rho_k) BE^T r = g + rho_{k+1} BE^T r
        if rho_new != rho:
            log.debug("SMALBE outer %d: penalty increased %.3g -> %.3g", k, up(rho, sc.a), up(rho_new, sc.a))
        rho = rho_new
        penalty[0] = rho
        g = g + rho * BTmul(r)
    else:
        reason = (f"max_outer {max_outer} reached: ||g^P|| = {gu(gp_norm):.3e}, "
                  f"||BE x - c|| = {xu(feas):.3e}")
    # back to the caller's units
    x = up(x, sc.x)
    np.maximum(x, lb_user, out=x)                    # exact unless a bound was subnormal in scaled units
    mu, rho, alpha = up(mu, sc.e), up(rho, sc.a), up(alpha, -sc.a)
    res = QPResult(
        x=x, converged=converged, reason=reason, iterations=total, outer_iterations=len(inner),
        inner_iterations=inner, n_hessian=n_hessian, n_cg=counts["cg"], n_expansion=counts["exp"],
        n_proportioning=counts["prop"], mu=mu, gradient_norms=np.asarray(gp_hist),
        constraint_norms=np.asarray(feas_hist), seconds=time.perf_counter() - t0,
        penalty=rho, alpha=alpha,
    )
    log.info("SMALBE n=%d m=%d: %s; %d outer, %d MPRGP steps %s, rho = %.3g",
             n, m, reason, res.outer_iterations, res.iterations, inner, rho)
    return res
