"""The active set method combined with the hybrid method (Chapter 5).

Problem (5.1) on the body-continuous interface space W^_{Gamma,c}:

    min 1/2 u^T S^_c u - g^_c^T u   s.t.   B^_{Gamma,c} u <= 0,

with (B^ u)_k = u^1 - u^2 at contact pair k and multipliers lambda >= 0 (KKT
conditions (5.5)). The algorithm of Chapter 5:

1. **Initial guess.** Solve the dual problem (5.4),
   min 1/2 lambda^T B^ M_BDDC^{-1} B^T lambda - d^T lambda, by PCG with the
   preconditioner M^{-1} = B^_D S^_c B^_D^T to ``pcg_rtol`` (1e-5). The
   membrane Omega^2 floats, so S^_c^dagger is approximated by
   P_R M_BDDC^{-1} P_R (the generalized inverse used by the hybrid's
   preconditioner (4.11)) and the equilibrium condition of the floating body,
   G^T lambda = R_c^T g^_c with G = B^ R_c (the constraint of the dual (6.14)),
   is imposed by the projection P = I - G (G^T G)^{-1} G^T exactly as in
   one-level FETI (2.13)-(2.14). (5.3)/(5.4) as printed omit this constraint;
   without it d^ has no information about the load that presses Omega^2 onto
   Omega^1.
2. **Projection in transformed coordinates (Figure 5.1).** lambda^ is the
   projection of lambda* onto {lambda >= 0} in the metric of
   M = (B^_D S^_c B^_D^T)^{-1}:
   min 1/2 (lambda - lambda*)^T M (lambda - lambda*) s.t. lambda >= 0. Its dual
   is the bound constrained QP min_{mu >= 0} 1/2 mu^T M^{-1} mu + mu^T lambda*,
   lambda^ = lambda* + M^{-1} mu, which needs only products with the
   preconditioner; it is solved by MPRGP (Figure 6.6) to 1e-10.
3. **Outer iterations (Figure 6.3, the active set method applied to the
   dual).** The face W_I fixes lambda_i = 0 for i in I; minimizing on it is the
   equality-constrained problem (4.2) on the active set Z^k = complement of I,
   solved by the hybrid PCR (:class:`~ddsolve.multibody.hybrid.HybridSolver`,
   no refactorization between outer iterations) to ``rtol`` (1e-5), warm
   started from the previous iterate (the first from (u, lambda) = (0, lambda^)).
   If the face minimizer y^ is feasible (lambda >= 0), it is accepted and
   I^{k+1} = B_0(x^{k+1}) = {i in I : (B^ u)_i <= 0}: pairs that penetrate
   join the active set. Otherwise Figure 6.3 moves to the cross point of the
   segment [x^k, y^] with {lambda >= 0} and I^{k+1} = A(x^{k+1}): the pair
   whose multiplier reached zero leaves the active set (``removal="blocking"``).
   That frees one pair per outer iteration, and the initial guess of step 2
   typically has a few too many pairs near the edge of the contact zone (24 at
   N = m = 20, costing 25 outer iterations). By default (``removal="all"``)
   every pair with a negative multiplier leaves at once and the projected face
   minimizer is the next iterate, as in primal-dual active set methods; an
   active set that would repeat falls back to the cross-point step. The
   iteration stops when a feasible face minimizer also satisfies B^ u <= 0
   (g^P = 0).

Inexact face solves make "= 0" and "<= 0" tests up to a tolerance:
``feasibility_tol`` (10 rtol by default) times ||lambda||_inf for multipliers
and times ||u_Gamma||_inf for the gap.
"""
from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from ..dd.common import MethodOutput
from ..dd.operators import linear_operator, scaled_jump
from ..errors import InputError, check_tolerance
from ..krylov import pcg
from ..krylov.result import KrylovResult
from ..multibody.fallback import broke_down_on_s_ol
from ..multibody.hybrid import RTOL_RULES, S_OL_FORMS, HybridSolver
from ..qp import mprgp
from ..qp.mprgp import check_count, check_positive
from ..qp.result import QPResult
from .direct import ContactSolution
from .problem import ContactProblem, kkt_verdict, series_stiffness

log = logging.getLogger(__name__)

__all__ = ["ActiveSetHybrid", "solve_contact_active_set", "INITIAL_ACTIVE", "REMOVALS", "FACE_NORMS", "SIGN_TESTS"]

#: Sign tests for penetration: ``"weighted"`` (default) (B u)_i > tol ||u||_inf or, as a force,
#: (B u)_i w_i > tol ||D u_Gamma||_inf (D = diag K, w the pair's two sides in series); ``"plain"`` the
#: first alone (Chapter 5 as printed).
SIGN_TESTS: tuple[str, ...] = ("weighted", "plain")
#: Initial active sets: {lambda^ > feasibility_tol max lambda^} (default) or {lambda^ > 0} (Chapter 5).
INITIAL_ACTIVE: tuple[str, ...] = ("relative", "positive")
#: Stopping norms of the face solves: l2 with the gaps weighted by max rho (default), Section 4.4's
#: plain l2, or the preconditioner's M-norm (:meth:`ActiveSetHybrid.face_norm_options`).
FACE_NORMS: tuple[str, ...] = ("scaled", "l2", "M")
#: Removal rules for negative multipliers: all at once (default) or Figure 6.3's blocking pair.
REMOVALS: tuple[str, ...] = ("all", "blocking")


class ActiveSetHybrid:
    """Active set method with the hybrid method for (3.1) (Chapter 5).

    Parameters
    ----------
    problem : ContactProblem
    hybrid : HybridSolver, optional
        Reused if given (its factorizations are shared by every outer iteration).

    Attributes
    ----------
    hybrid : HybridSolver
    n_contact : int
        Number of contact multipliers.
    """

    def __init__(self, problem: ContactProblem, hybrid: HybridSolver | None = None) -> None:
        self.problem = problem
        self.hybrid = hybrid if hybrid is not None else HybridSolver(problem.sub, problem.gi)
        self.n_contact = problem.n_contact
        #: every contact pair active: B^_{Gamma,c}, its scaled version and G = B^ R_c
        self.all_pairs = self.hybrid.active_set(np.ones(self.n_contact, dtype=bool))

    # ------------------------------------------------------------- operators
    def B(self, u: np.ndarray) -> np.ndarray:
        """B^_{Gamma,c} u, shape (n_gamma,) -> (n_c,)."""
        return self.hybrid.jump(self.all_pairs, u)

    def BT(self, lam: np.ndarray) -> np.ndarray:
        """B^_{Gamma,c}^T lam, shape (n_c,) -> (n_gamma,)."""
        return self.hybrid.jump_transpose(self.all_pairs, lam)

    def face_u(self, out: MethodOutput) -> np.ndarray:
        """u, shape (ndof,), of a face solve made with ``interior=False``: its interior values now, from its
        u_Gamma (:meth:`~ddsolve.multibody.hybrid.HybridSolver.extend`), for the last face solve only."""
        return out.u if out.u is not None else self.hybrid.extend(out.extra["u_gamma"])

    def S_dagger(self, r: np.ndarray) -> np.ndarray:
        """P_R M_BDDC^{-1} P_R r, the stand-in for S^_c^dagger in (5.4), shape (n_gamma,)."""
        h = self.hybrid
        return h.P_R(h.M_bddc(h.P_R(r)))

    def F(self, lam: np.ndarray) -> np.ndarray:
        """Operator of (5.4): B^ P_R M_BDDC^{-1} P_R B^T lam, shape (n_c,) -> (n_c,)."""
        return self.B(self.S_dagger(self.BT(lam)))

    def preconditioner(self, lam: np.ndarray) -> np.ndarray:
        """M^{-1} lam = B^_D S^_c B^_D^T lam (Chapter 5), shape (n_c,) -> (n_c,).

        B^_D scales the entry of the Omega^1 copy by the body weight of the
        Omega^2 copy and vice versa (``gi.weight``).
        """
        return scaled_jump(self.all_pairs.scaled_jump_gamma, self.hybrid.S_hat)(lam)

    def face_norm_options(self, face_norm: str) -> dict[str, Any]:
        """Keywords of :meth:`HybridSolver.solve` for a face solve's stopping norm.

        ``"scaled"``: ``norm="l2"`` with ``multiplier_weight`` c = max_i rho_i, the
        coefficient scale (||S^_c|| = O(max rho) for the 2D stiffness): the residual
        (||r_u||^2 + c^2 ||r_lambda||^2)^{1/2} adds forces to forces, so the rule, and
        with it every iteration count, is invariant under rho -> s rho and f -> t f.
        For rho = 1 it is the thesis's ||.||_2 exactly (c = 1).
        ``"l2"``: c = 1 at any rho (Section 4.4 as printed). ``"M"``: ``norm="M"``.
        """
        if face_norm == "M":
            return {"norm": "M"}
        if face_norm == "l2":
            return {"norm": "l2"}
        c = self.coefficient_scale()
        return {"norm": "l2", "multiplier_weight": c if c > 0.0 and np.isfinite(c) else 1.0}

    def gamma_stiffness(self) -> np.ndarray:
        """|diag K| on the u_Gamma dofs, shape (n_gamma,) (replicated under mpiexec): the weights of the
        sign test ``sign_test="weighted"``."""
        return self.problem.stiffness()[self.hybrid.gamma_space.dofs]

    def pair_stiffness(self, d_gamma: np.ndarray) -> np.ndarray:
        """:func:`~ddsolve.contact.problem.series_stiffness` of every contact pair, shape (n_c,), from
        ``d_gamma`` = :meth:`gamma_stiffness`."""
        pair = self.hybrid._pair_gamma
        return series_stiffness(d_gamma[pair[:, 0]], d_gamma[pair[:, 1]])

    def coefficient_scale(self) -> float:
        """max_i rho_i over all subdomains (1 without subdomains): c of ``face_norm="scaled"``."""
        rho = np.asarray(self.problem.sub.rho, dtype=float)
        return float(rho.max()) if rho.size else 1.0

    # ---------------------------------------------------------- initial guess
    def initial_multipliers(self, rtol: float = 1e-5, maxiter: int = 1000
                            ) -> tuple[np.ndarray, np.ndarray, KrylovResult, QPResult]:
        """Steps 1-2 of Chapter 5: lambda* of (5.4) and its projection lambda^.

        Returns
        -------
        lam_star, lam_hat : ndarray, shape (n_c,)
        pcg_result : KrylovResult
            The projected PCG on (5.4).
        projection : QPResult
            MPRGP on the dual of the projection problem.
        """
        h, pairs = self.hybrid, self.all_pairs
        n = self.n_contact
        d = self.B(self.S_dagger(h.g_hat))
        P_op = None
        lam0 = np.zeros(n)
        if h.floating.size:
            # (2.13): lambda_0 with G^T lambda_0 = e = R_c^T g^_c, and P = I - G (G^T G)^{-1} G^T
            lam0 = pairs.projection.particular(h.kernel_load())
            P_op = linear_operator(n, pairs.projection.apply)
        F = linear_operator(n, self.F)
        M = linear_operator(n, self.preconditioner)
        b = d - self.F(lam0)
        kr = pcg(F, b, rtol=rtol, maxiter=maxiter, M=M, P=P_op)
        lam_star = lam0 + kr.x
        try:
            qp = mprgp(M, -lam_star, np.zeros(n), rtol=1e-10, maxiter=50 * n + 100)
        except InputError as exc:       # not the user's input: an operator or load beyond the double range
            raise FloatingPointError(f"the projection problem of (5.4) is not finite ({exc})") from None
        lam_hat = np.maximum(lam_star + self.preconditioner(qp.x), 0.0)
        log.info("active set: PCG on (5.4) %s; projection %s", kr.reason, qp.reason)
        return lam_star, lam_hat, kr, qp

    # ------------------------------------------------------------------ solve
    def solve(self, *, rtol: float = 1e-5, pcg_rtol: float = 1e-5, maxiter: int = 1000, max_outer: int = 50,
              feasibility_tol: float | None = None, removal: str = "all",
              forcing: float | None = None, face_rtol_rule: str = "max",
              initial_active: str = "relative", face_norm: str = "scaled",
              s_ol: str = "thesis", s_ol_fallback: bool = True, sign_test: str = "weighted") -> ContactSolution:
        """Run the active set method.

        Parameters
        ----------
        rtol : float
            Tolerance of each hybrid face solve (residual reduction, 1e-5 in the thesis).
        pcg_rtol : float
            Tolerance of the PCG on (5.4) (1e-5 in the thesis).
        maxiter : int
            Iteration limit of each Krylov solve.
        max_outer : int
            Limit of outer iterations (face solves).
        feasibility_tol : float, optional
            Relative tolerance of the sign tests (default 10 rtol).
        removal : {"all", "blocking"}
            What happens when a face minimizer has negative multipliers.
            ``"blocking"`` is Figure 6.3 literally: move to the cross point of
            the segment with {lambda >= 0} and free the pair that blocks it
            (one pair per outer iteration). ``"all"`` (default) frees every pair
            with a negative multiplier at once and keeps the face minimizer
            (projected onto lambda >= 0) as the next iterate and warm start, as
            primal-dual active set methods do; an active set that would repeat
            falls back to the cross-point step, so the iteration cannot cycle.
        forcing : float, optional
            Inexact face solves (an inexact-Newton-style forcing term): while
            the active set still changes, face solves stop at
            ``max(forcing, rtol)`` instead of ``rtol`` and the sign tests use
            ``max(feasibility_tol, forcing)``. The first face whose loose minimizer
            would end the iteration is solved again to ``rtol`` (warm started),
            and from then on every face solve uses ``rtol``, so the iteration
            still stops only on a face minimizer computed to ``rtol`` that
            passes the sign tests at ``feasibility_tol``. None (default): every
            face solve to ``rtol`` (Chapter 5 as printed).
        face_rtol_rule : {"max", "initial"}
            Stopping rule of every face solve (:meth:`HybridSolver.solve`'s
            ``rtol_rule``): ``"max"`` (default) ||r_k|| <= rtol max(||r_0||, ||F||),
            so a warm start stops where a cold start would; ``"initial"``
            ||r_k|| <= rtol ||r_0|| (the thesis's rule, also for warm starts).
        face_norm : {"scaled", "l2", "M"}
            Norm of every face solve's stopping rule (:meth:`face_norm_options`):
            ``"scaled"`` (default) ||.||_2 with the multiplier block (gaps, ~ 1/rho)
            weighted by the coefficient scale max rho, invariant under rho -> s rho;
            ``"l2"`` the plain ||.||_2 of Section 4.4 (the thesis preset), which adds
            forces (~ rho) to displacements (~ 1/rho); ``"M"`` the preconditioner's norm.
        initial_active : {"relative", "positive"}
            The initial active set: ``"relative"`` (default)
            {lambda^_i > feasibility_tol max lambda^} (the projection by MPRGP
            to 1e-10 leaves round-off-sized positive entries off the contact
            zone); ``"positive"`` {lambda^_i > 0} (Chapter 5 as printed).
        s_ol : {"thesis", "energy"}
            Form of S~_OL in the hybrid's preconditioner (4.11) (:meth:`HybridSolver.solve`):
            ``"thesis"`` (default) S_GG - S_G0 M_0 S_0G of (4.9)-(4.10), ``"energy"`` the
            positive semidefinite E^T S E.
        s_ol_fallback : bool
            With ``s_ol="thesis"``: when a face solve breaks down because the
            preconditioner is not positive definite (S~_OL indefinite), solve that
            face again (same warm start) with ``s_ol="energy"`` and keep the energy
            form for the remaining faces; ``extra["s_ol_fallback"]`` lists the face
            solves (1-based) redone. True by default; False (the thesis preset):
            the breakdown ends the run with ``converged=False``.
        sign_test : {"weighted", "plain"}
            The test for penetrating pairs outside the active set (:data:`SIGN_TESTS`):
            ``"plain"`` (B u)_i > feasibility_tol ||u_Gamma||_inf (Chapter 5 as printed, the
            thesis preset); ``"weighted"`` (default) also (B u)_i w_i > feasibility_tol
            ||D u_Gamma||_inf, the penetration as a force (D = diag K, w_i the pair's two
            sides in series). Under coefficient jumps a stiff pair's penetration is small
            against the soft bodies' displacements: the plain test stopped at checkerboards
            of 1e12 with lambda 27-150% off (a review).

        Returns
        -------
        ContactSolution
            ``inner_iterations``: PCR iterations of each face solve;
            ``pcg_iterations``: PCG iterations on (5.4); ``extra`` holds
            ``lambda_star``, ``lambda_hat``, ``initial_active``,
            ``projection_iterations``, ``active_history``, ``s_ol`` (the form in use at
            the end), ``s_ol_fallback`` (face solves redone with the energy form) and
            ``s_ol_breakdown_iterations`` (PCR iterations of their broken-down first attempts,
            not in ``inner_iterations``).
        """
        t0 = time.perf_counter()
        rtol, pcg_rtol = check_tolerance("rtol", rtol), check_tolerance("pcg_rtol", pcg_rtol)
        maxiter, max_outer = check_count("maxiter", maxiter, 1), check_count("max_outer", max_outer, 1)
        if forcing is not None:
            forcing = check_tolerance("forcing", forcing)
        for name, value, allowed in (("removal", removal, REMOVALS), ("face_rtol_rule", face_rtol_rule, RTOL_RULES),
                                     ("initial_active", initial_active, INITIAL_ACTIVE),
                                     ("face_norm", face_norm, FACE_NORMS), ("s_ol", s_ol, S_OL_FORMS),
                                     ("sign_test", sign_test, SIGN_TESTS)):
            if not isinstance(value, str) or value not in allowed:      # InputError (a ValueError), naming it
                raise InputError(name, f"must be one of {', '.join(allowed)}, got {value!r}")
        if feasibility_tol is not None:
            feasibility_tol = check_positive("feasibility_tol", feasibility_tol, strict=False)
        d_gamma = self.gamma_stiffness() if sign_test == "weighted" else None
        w_pair = self.pair_stiffness(d_gamma) if d_gamma is not None else None
        fallback_faces: list[int] = []
        broken_iterations: list[int] = []
        face_norm_options = self.face_norm_options(face_norm)
        tol = 10.0 * rtol if feasibility_tol is None else float(feasibility_tol)
        h, n = self.hybrid, self.n_contact
        lam_star, lam_hat, kr0, qp = self.initial_multipliers(pcg_rtol, maxiter)
        if initial_active == "positive":
            active = lam_hat > 0.0
        else:
            active = lam_hat > tol * max(float(lam_hat.max()), 1e-300)
        if not active.any():
            active[int(np.argmax(lam_star))] = True
        initial_active = active.copy()
        lam_k = np.where(active, lam_hat, 0.0)              # x^0, feasible
        u_k = np.zeros(h.n_gamma)
        inner: list[int] = []
        history = [int(active.sum())]
        converged, reason = False, f"active set not settled after {max_outer} outer iterations"
        out: Any = None
        seen = {np.packbits(active).tobytes()}
        loose = forcing is not None and float(forcing) > rtol
        face_tols: list[float] = []
        for _ in range(max_outer):
            face_rtol = float(forcing) if loose else rtol
            sign_tol = max(tol, face_rtol) if loose else tol
            face = {"rtol": face_rtol, "maxiter": maxiter, "x0": {"u_gamma": u_k, "lambda": lam_k},
                    "rtol_rule": face_rtol_rule, "check": False, "interior": False, **face_norm_options}
            out = h.solve(active, s_ol=s_ol, **face)
            if s_ol_fallback and s_ol == "thesis" and broke_down_on_s_ol(out.krylov):
                # S~_OL of (4.9)-(4.10) indefinite: redo the face with the PSD energy form (docs/methods.md)
                log.warning("active set: face solve %d broke down (%s); solving it again with s_ol='energy'",
                            len(inner) + 1, out.krylov.reason)
                fallback_faces.append(len(inner) + 1)
                broken_iterations.append(int(out.krylov.iterations))
                s_ol = "energy"
                out = h.solve(active, s_ol=s_ol, **face)
            inner.append(int(out.krylov.iterations))
            face_tols.append(face_rtol)
            if not out.krylov.converged:
                reason = f"face solve {len(inner)} did not converge: {out.krylov.reason}"
                if fallback_faces and fallback_faces[-1] == len(inner):
                    reason += " (after a breakdown with s_ol='thesis', solved again with s_ol='energy')"
                break
            lam_y = np.zeros(n)
            lam_y[active] = out.extra["lambda"]
            u_y = out.extra["u_gamma"]
            lam_scale = max(float(np.abs(lam_y).max()), 1e-300)
            negative = active & (lam_y < -sign_tol * lam_scale)
            if (negative.any() and removal == "all"
                    and np.packbits(active & ~negative).tobytes() not in seen):
                # free every pair with a negative multiplier at once (projected iterate)
                lam_k = np.where(negative, 0.0, np.maximum(lam_y, 0.0))
                u_k = u_y
                active = active & ~negative
            elif negative.any():
                # cross point of [x^k, y^] with {lambda >= 0}; the blocking pairs leave the face
                ratios = lam_k[negative] / (lam_k[negative] - lam_y[negative])
                alpha = float(np.clip(ratios.min(), 0.0, 1.0))
                lam_k = lam_k + alpha * (lam_y - lam_k)
                u_k = u_k + alpha * (u_y - u_k)
                blocking = negative & (lam_k <= tol * lam_scale)
                blocking[np.flatnonzero(negative)[int(np.argmin(ratios))]] = True
                lam_k[blocking] = 0.0
                active = active & ~blocking
                if not active.any():
                    reason = "the active set became empty (the floating membrane lost contact)"
                    break
            else:
                lam_k = np.maximum(lam_y, 0.0)
                u_k = u_y
                gap = self.B(u_y)
                penetrating = ~active & (gap > sign_tol * max(float(np.abs(u_y).max()), 1e-300))
                if w_pair is not None:      # the penetration as a force (sign_test="weighted")
                    force_scale = float(np.abs(d_gamma * u_y).max(initial=0.0))
                    if force_scale > 0.0:
                        penetrating |= ~active & (gap * w_pair > sign_tol * force_scale)
                if not penetrating.any() and loose:
                    loose = False                   # solve this face again to rtol (warm started)
                    continue
                if not penetrating.any():
                    converged = True
                    reason = f"KKT conditions hold after {len(inner)} outer iteration(s)"
                    break
                active = active | penetrating
            seen.add(np.packbits(active).tobytes())
            history.append(int(active.sum()))
        if fallback_faces and converged:
            reason += (f"; face solve(s) {', '.join(map(str, fallback_faces))} redone with s_ol='energy' after "
                       "a breakdown with the indefinite S~_OL of (4.9)-(4.10)")
        u = self.face_u(out) if out is not None else np.zeros(self.problem.ndof)
        lam = lam_k if converged else np.where(active, lam_k, 0.0)
        seconds = time.perf_counter() - t0
        log.info("active set + hybrid: %s", reason)
        return ContactSolution(
            u=u, lam=lam, active=lam > 0, converged=converged, reason=reason,
            outer_iterations=len(inner), inner_iterations=inner, pcg_iterations=int(kr0.iterations),
            seconds=seconds, n_factorizations=int(h.n_factorizations),
            extra={"lambda_star": lam_star, "lambda_hat": lam_hat, "initial_active": initial_active,
                   "projection_iterations": int(qp.iterations), "active_history": history,
                   "pcg_converged": bool(kr0.converged), "setup_seconds": float(h.setup_seconds),
                   "face_rtol": face_tols, "s_ol": s_ol, "s_ol_fallback": fallback_faces,
                   "s_ol_breakdown_iterations": broken_iterations})


def solve_contact_active_set(problem: ContactProblem, *, rtol: float = 1e-5, pcg_rtol: float = 1e-5,
                             maxiter: int = 1000, max_outer: int = 50,
                             solver: ActiveSetHybrid | None = None, removal: str = "all",
                             face_rtol_rule: str = "max", initial_active: str = "relative",
                             face_norm: str = "scaled", s_ol: str = "thesis",
                             s_ol_fallback: bool = True, sign_test: str = "weighted") -> ContactSolution:
    """Solve (3.1) by the active set method with the hybrid method (Chapter 5).

    See :meth:`ActiveSetHybrid.solve` (``removal``, ``face_rtol_rule``, ``initial_active``,
    ``s_ol_fallback``, ``sign_test``: the defaults are the project's rules, the thesis preset passes
    "blocking", "initial", "positive", False, "plain"); ``solver`` reuses its factorizations. The solution's ``seconds``
    include building the solver here, and ``extra["setup_seconds"]`` is that part (0 for a given
    ``solver``), so that ``seconds - setup_seconds`` is the solve phase.
    """
    setup = 0.0
    if solver is None:
        t0 = time.perf_counter()
        solver = ActiveSetHybrid(problem)
        setup = time.perf_counter() - t0
    sol = solver.solve(rtol=rtol, pcg_rtol=pcg_rtol, maxiter=maxiter, max_outer=max_outer, removal=removal,
                       face_rtol_rule=face_rtol_rule, initial_active=initial_active, face_norm=face_norm,
                       s_ol=s_ol, s_ol_fallback=s_ol_fallback, sign_test=sign_test)
    # seconds and extra["setup_seconds"] as every contact solver reports them: the total of this call,
    # of which the setup (the hybrid's factorizations, when built here; 0 when a built solver is reused)
    sol.seconds += setup
    sol.extra["setup_seconds"] = setup
    # the face-solve rules bound residuals, not the KKT conditions (5.5): the acceptance rule of every
    # iterative contact solve (rtol 0.5 returned a KKT residual of 0.42, lambda 200% off, "converged")
    # and, weighted by the stiffness, penetrating pairs under a coefficient jump (both sign tests)
    sol.kkt = problem.kkt(sol.u, sol.lam)
    weighted = problem.weighted_feasibility(sol.u)
    sol.extra["kkt_weighted_feasibility"] = weighted
    sol.converged, sol.reason = kkt_verdict(sol.converged, sol.reason, sol.kkt.max, rtol, weighted)
    return sol
