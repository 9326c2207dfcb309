"""SMALBE with MPRGP on the FETI-DP dual of the two-membrane contact problem (3.1) (Section 6.4).

The formulation, (6.13) -> (6.14)-(6.15) -> (6.16) -> (6.17), and the primal recovery are the
chain of transforms of :mod:`ddsolve.contact.smalbe_chain` (its module docstring); this module
drives it (:func:`solve_contact_smalbe`): parameters, stopping rule, acceptance check, polish.

Problem (6.17) is solved by :func:`ddsolve.qp.smalbe` (Figure 6.7) for the equality
G lambda = 0 with MPRGP inner solves (Figure 6.6), M = 1, rho_0 = 30,
Gamma = 1, eps = 1e-5 (Section 6.4). Choices not stated in the thesis:

* Units. M, rho_0 and rho_bar are absolute numbers in the units of
  F = B A~^+ B^T (~ 1/rho), and ||b|| is a displacement while G lambda is a
  force. With F_scale = 1 / min rho (:class:`~ddsolve.contact.smalbe_chain.DualProblem`,
  1 for rho = 1) the defaults are M = F_scale, rho_0 = 30 F_scale,
  rho_bar = F_scale, and ||b|| enters the equality rule below as the force
  ||b|| / F_scale: the default run is invariant under rho -> s rho and
  f -> t f (same iterations, u -> (t/s) u, lambda -> t lambda), and for
  rho = 1 it is the run with the thesis's numbers. Explicit values are used
  as given.
* Stopping rule. Section 6.4 stops when ||g^P|| <= eps ||b|| and
  ||G lambda|| <= eps ||b||, b = P d. We keep the first and tighten the
  second to ||G lambda|| <= eps min(||b|| / F_scale, ||e||), ||e|| = |e~| / sqrt(n_c)
  the right-hand side of G lambda = e in (6.15) (a relative residual of
  that equation). Reason: G lambda is the force imbalance of the floating
  body, -||G~|| G lambda = R^T (f_W - B^T (lambda + lambda~)), and the
  recovery below turns it into a contact force error of at most
  ||G lambda|| / ||e|| times the net load -e~. ||b|| is dominated by the
  self-balanced part of the load, so with eps ||b|| alone the contact force
  was unresolved whenever the net load is small against it: a one-node
  contact zone came out 1.4 % off and a floating body pressed on by a net
  load 1e-8 got sum(lambda) = 1e-4 (stress study, ``contact_single_node``
  and ``contact_barely``), both with converged=True; on the Table 6.1 grids
  the same defect gave KKT stationarity 6e-5..3e-3 and lambda errors up to
  5e-3. ``feas_tol`` of :func:`ddsolve.qp.smalbe` carries the tighter value;
  SMALBE itself (Figure 6.7) is unchanged.
* rho_bar = 1 F_scale (default; ``rho_bar=`` overrides, ``None`` takes the ARPACK
  estimate of ||P F P||, the previous default). Without bounds the equality
  part of an outer iteration contracts G lambda by rho_bar / (rho_bar + rho),
  so rho_bar = ||P F P|| (~100-400 here) against rho_0 = 30 needs 5-20
  times more outer iterations to resolve G lambda to eps ||e||: with the rule
  above, 30-70 outer iterations on the (8, 8) and (12, 12) grids of
  Table 6.1 against 7-10 with rho_bar = 1 (all 25 grids: 4-20 outer, 24-261
  MPRGP steps, thesis 4-14 and 41-396). ||P F P|| is still estimated
  (ARPACK Lanczos, ``eigsh``, seeded start, tol 1e-6) for the steplength:
  P F P and Q act on orthogonal complements, so ||P F P + rho_bar Q|| =
  max(||P F P||, rho_bar) and the inner Hessian P F P + (rho_bar + rho) Q of
  SMALBE has norm max(||P F P||, rho_bar + rho) <= max(||P F P||, rho_bar) +
  rho, which is what SMALBE's steplength 1.9 / (||A|| + rho ||G||^2) uses
  (``norm_A = (1 + 1e-3) max(||P F P||, rho_bar)``, ``norm_BE = 1``), inside
  (0, 2/||Hessian||].
* eta = 0.1 ||b|| and beta = 10 (the defaults of :func:`smalbe`); the start is
  lambda^0 = 0, i.e. lambda_full = lambda~ (uniform pressure); mu^0 = 0;
  at most 100 outer iterations (``max_outer``).

Acceptance check, refinement and rescue
---------------------------------------
After SMALBE stops, the returned pair must have finite values, balance the
floating body: |sum(lam) - net| <= 10 eps net (``FORCE_FACTOR``), net =
-e~ = -integral of f over Omega^2 (``extra["force_error"]``), and have a KKT
stationarity of :meth:`ContactProblem.kkt` of at most 100 eps
(``STATIONARITY_FACTOR``; 1..7 eps on the Table 6.1 grids, but up to ~1e6 eps
with coefficient jumps, since the dual rule is relative to ||b||) and a
penetration weighted by the stiffness (:meth:`ContactProblem.weighted_feasibility`)
of at most :func:`~ddsolve.contact.problem.kkt_limit` (eps). The
stopping rule guarantees the force balance (force error <= eps) for a
converged run; failing either check turns converged into False with the
reason. With ``polish="auto"`` (default) every converged result is then
refined by the FETI-FETI solve on its active set described below and
replaced by it if that lowers the KKT residual (SMALBE's iterations are
unchanged; with a subdomain checkerboard of 1e4 SMALBE alone leaves lambda
off by 1e-2 at a stationarity of 2 eps, the refined lambda agrees with the
direct reference to 1e-8). SMALBE can stop short of the
rule: the equality part contracts slowly when few contact rows are off their
bound (G restricted to the free rows has norm sqrt(n_free / n_c); a one-node
zone on (8, 16) takes more than 100 outer iterations), or G lambda would
have to reach round-off (net load 1e-8 against ||b|| ~ 1). If its last
iterate meets the rule of Section 6.4 (||G lambda|| <= eps ||b||) but not the
force rule, ``polish="auto"`` (default) solves the equality-constrained
problem on SMALBE's active set by FETI-FETI PCG (3.35), whose natural coarse
space enforces the balance exactly, and returns it with converged=True only
if its multipliers are >= 0 and its gaps <= 0 (to 10 eps), it passes the
force check and it lowers the KKT residual of :meth:`ContactProblem.kkt`:
then it satisfies the KKT conditions (5.5) to that tolerance. Otherwise
converged=False with the reason (e.g. a wrong active set: a negative
multiplier). The stress study's one-node and barely-pressed cases at N = m =
8 pass this way (one-node: converged by the rule in 91 outer iterations;
barely: rescued, lambda error 1.3e-5).

Attainable accuracy
-------------------
The stopping rule bounds the dual gradient (displacement jumps and gaps) by
eps ||b|| and the contact force error by eps net. The primal force residual
K u - f + B^T lam is K times the jumps of u~ plus the force error of the
zeroed inactive entries; with the KKT measure of :meth:`ContactProblem.kkt`
it is 1e-5..7e-5 at eps = 1e-5 on the 25 Table 6.1 grids (it was 6e-5..3e-3
with eps ||b|| on G lambda and rho_bar = ||P F P||), while feasibility,
complementarity, ||u - u_ref|| and the lambda error stay at or below ~eps.
"""
from __future__ import annotations

import logging
import math
import time

import numpy as np

from ..krylov.convergence import norm2
from ..multibody.fetifeti import FetiFetiSolver
from ..qp.result import QPResult
from .direct import ContactSolution
from .problem import ContactProblem, kkt_limit, kkt_verdict
from .smalbe_chain import (
    NORM_SAFETY,
    DualProblem,
    EnforcedProblem,
    HomogeneousProblem,
    RecoveredSolution,
    dualize,
    enforce,
    homogenize,
    map_back,
    solve_enforced,
)

__all__ = ["solve_contact_smalbe", "DEFAULT_M", "DEFAULT_RHO0", "DEFAULT_RHO_BAR", "RELATIVE", "FORCE_FACTOR", "STATIONARITY_FACTOR", "EQUALITY_RULES",
           "ACCEPTANCE", "POLISH_MAXITER", "NORM_SAFETY", "DualProblem", "dualize", "HomogeneousProblem",
           "homogenize", "EnforcedProblem", "enforce", "solve_enforced", "RecoveredSolution", "map_back"]

log = logging.getLogger(__name__)

#: Defaults of SMALBE's absolute parameters, in units of F = B A~^+ B^T (times ``F_scale`` =
#: 1 / min rho, :class:`~ddsolve.contact.smalbe_chain.DualProblem`; the values themselves for rho = 1):
#: the precision control M and the initial penalty rho_0 of Section 6.4, and rho_bar of (6.17)
#: (the thesis: any positive constant; module docstring).
DEFAULT_M = 1.0
DEFAULT_RHO0 = 30.0
DEFAULT_RHO_BAR = 1.0
#: ``rho_bar`` value selecting the default DEFAULT_RHO_BAR F_scale.
RELATIVE = "relative"
#: Acceptance check: |sum(lambda) - net load| <= FORCE_FACTOR eps net load.
FORCE_FACTOR = 10.0
#: Acceptance check: relative KKT stationarity (ContactProblem.kkt) <= STATIONARITY_FACTOR eps.
#: SMALBE's own rule bounds the dual gradient (displacement jumps) relative to ||b||; with
#: coefficient jumps K turns them into force residuals up to ~1e6 eps (rho = 1 / 1e-6 across
#: the membranes). On the Table 6.1 grids (rho = 1) it is 1..7 eps.
STATIONARITY_FACTOR = 100.0
#: Equality parts of the stopping rule: ||G lambda|| <= eps min(||b||, ||e||) (default, module
#: docstring) or eps ||b|| (Section 6.4 as printed, the thesis preset).
EQUALITY_RULES: tuple[str, ...] = ("min", "section-6.4")
#: What a failed acceptance check does: turn converged into False (default) or only get reported
#: (Section 6.4 has no check; the thesis preset).
ACCEPTANCE: tuple[str, ...] = ("enforce", "report")
#: PCG iteration limit of the FETI-FETI solve on the active set (polish): it needs 8..18 on the
#: Table 6.1 grids; at eps near round-off (1e-10) its target eps x the warm start's residual is out
#: of reach, and the limit bounds the cost of finding that out (the result is then rejected).
POLISH_MAXITER = 100



def solve_contact_smalbe(problem: ContactProblem, *, eps: float = 1e-5, M: float | None = None,
                         rho0: float | None = None,
                         Gamma: float = 1.0, maxiter: int | None = None,
                         solver: FetiFetiSolver | None = None, rho_bar: float | str | None = RELATIVE,
                         polish: bool | str = "auto", max_outer: int = 100,
                         equality_rule: str = "min", acceptance: str = "enforce",
                         halfstep: bool = True) -> ContactSolution:
    """Solve (3.1) by SMALBE/MPRGP on the FETI-DP dual (6.17) (thesis Section 6.4).

    See the module docstring for the formulation (6.13)-(6.17), the stopping rule
    and the acceptance check.

    Parameters
    ----------
    problem : ContactProblem
        Assembled two-membrane problem (one clamped and one floating body).
    eps : float
        Relative tolerance of the outer stopping rule: ``||g^P|| <= eps ||b||``
        (Section 6.4, b = P d) and ``||G lambda|| <= eps min(||b||, ||e||)``
        (Section 6.4 has ``eps ||b||``; ``||e||`` is the right-hand side of
        G lambda = e in (6.15), the net load on Omega^2 / sqrt(n_c): this bounds
        the contact force error by ``eps`` times the net load). Also the
        tolerance of the acceptance check (``FORCE_FACTOR eps``).
    M, rho0 : float, optional
        SMALBE precision control constant and initial penalty (Section 6.4: 1 and 30).
        They are absolute numbers in the units of F = B A~^+ B^T (~ 1/rho); the defaults
        (None) are :data:`DEFAULT_M` and :data:`DEFAULT_RHO0` times ``F_scale`` = 1 / min rho
        (the thesis's 1 and 30 for rho = 1), so that the default run is invariant under
        rho -> s rho. An explicit value is used as given (its meaning is absolute).
    Gamma : float
        MPRGP proportioning parameter (Section 6.4: 1; dimensionless).
    maxiter : int, optional
        Maximum total number of MPRGP steps (default of :func:`ddsolve.qp.smalbe`,
        ``max(200, 20 n_lambda)``).
    solver : FetiFetiSolver, optional
        Prebuilt FETI-FETI operators of ``problem.sub`` / ``problem.gi`` (their
        factorizations are reused); built here when not given.
    rho_bar : float, "relative" or None
        The constant rho_bar > 0 of (6.17): ``"relative"`` (default) :data:`DEFAULT_RHO_BAR`
        ``F_scale`` (1 for rho = 1); a number: that absolute value; ``None``: the estimate
        of ||P F P|| (the default before; slower: the equality part contracts by
        rho_bar / (rho_bar + rho) per outer iteration).
    polish : {"auto", True, False}
        ``True``: after a converged SMALBE, solve the equality-constrained problem
        on the active set it found by FETI-FETI PCG (3.35), warm started from its
        multipliers and stopped at ``eps`` times the warm start's residual, and
        return that (u, lambda) if its multipliers stay >= 0 and its gaps <= 0
        (to 10 eps) and it passes the acceptance check. ``"auto"`` (default): the
        same solve after a converged SMALBE, kept only if it also lowers the KKT
        residual of :meth:`ContactProblem.kkt` (otherwise SMALBE's pair is
        returned); and as a rescue, when SMALBE did not converge but its last
        iterate meets the rule of Section 6.4 (``||G lambda|| <= eps ||b||``, not
        ``eps ||e||``: the contact force is under-resolved), or when a converged
        result fails the acceptance check (force balance, or KKT stationarity
        above ``STATIONARITY_FACTOR eps``, as with coefficient jumps); the rescued
        result is converged only if it lowers the KKT residual. ``False``: never
        (Section 6.4 has no such step). Its PCG iterations are
        ``extra["polish_iterations"]``, not part of ``inner_iterations``.
    max_outer : int
        Maximum number of SMALBE outer iterations.
    equality_rule : {"min", "section-6.4"}
        Equality part of the stopping rule: ``"min"`` (default)
        ``||G lambda|| <= eps min(||b|| / F_scale, ||e||)`` (||b|| / F_scale: the
        displacement ||b|| in force units, invariant under rho -> s rho; ||b|| for
        rho = 1); ``"section-6.4"`` ``||G lambda|| <= eps ||b||`` as printed (the thesis
        preset, with ``rho_bar=None`` and ``polish=False``; not invariant under rho -> s rho).
    acceptance : {"enforce", "report"}
        ``"enforce"`` (default): a result that fails the acceptance check (force
        balance, KKT stationarity) is ``converged=False``. ``"report"``: the
        verdict is SMALBE's stopping rule alone (Section 6.4 has no such check);
        the check is still made and its outcome recorded in ``extra["acceptance"]``
        and in the reason (the thesis preset).
    halfstep : bool
        MPRGP's expansion steps preceded by the feasible half step to the boundary (default:
        Dostál's MPRGP, monotone decrease of the cost; :func:`ddsolve.qp.mprgp.mprgp`) or not
        (``False``: Figure 6.6 as printed, the thesis preset).

    Returns
    -------
    ContactSolution
        ``u`` (ndof,); ``lam`` (n_c,), the contact multipliers in ``problem.gi`` pair
        order (>= 0; 0 off the active set); ``active`` (n_c,), the contact rows off
        their bound in the SMALBE iterate with positive balanced multiplier (so
        ``active == (lam > 0)``); ``outer_iterations`` (SMALBE outer iterations);
        ``inner_iterations`` (MPRGP steps per outer iteration); ``seconds`` (wall
        time of the call, FETI-FETI setup included when built here);
        ``n_factorizations`` (of the solver built here; 0 when ``solver`` is passed);
        ``extra``: ``nlambda, n_local, n_contact`` (row counts of B), ``n_hessian,
        n_cg, n_expansion, n_proportioning`` (SMALBE counters), ``n_Fmult`` (all
        products with F, norm estimate included), ``n_norm_estimate``, ``penalty``
        (final rho), ``rho_bar``, ``norm_PFP``, ``alpha`` (last MPRGP steplength),
        ``lambda_tilde`` (uniform homogenization pressure), ``mu`` (SMALBE multiplier
        of G lambda = 0), ``lambda`` (n_lambda,) the balanced P lambda + lambda~,
        ``equality_defect`` (G lambda), ``rigid_alpha``, ``local_jump``
        (||B_loc u~||_2), ``norm_b`` (||P d||), ``norm_e`` (||e||), ``tol_equality``
        (the tolerance on ||G lambda||), ``net_load`` (-integral of f over Omega^2),
        ``force_error`` (|sum(lam) - net load| / net load), ``kkt`` (the four relative
        KKT residuals of the returned pair), ``gradient_norms``, ``constraint_norms``
        (per outer iteration), ``setup_seconds``, ``qp_seconds``, ``polish``
        (``"accepted"`` / ``"rejected"`` when tried), ``polish_iterations``,
        ``u_unpolished`` (ndof,) and ``lambda_unpolished`` (n_c,): SMALBE's own recovered
        pair before any polish (the returned pair when there was none).
        Non-convergence, and a result that fails the acceptance check, give
        ``converged=False`` and a reason; nothing is raised for it.
    """
    t0 = time.perf_counter()
    if isinstance(eps, bool) or not isinstance(eps, (int, float, np.integer, np.floating)) or not 0 < eps < 1:
        return _failure(problem, t0, f"eps must be a number in (0, 1), got {eps!r}")
    if polish not in ("auto", True, False):
        return _failure(problem, t0, f"polish must be 'auto', True or False, got {polish!r}")
    if acceptance not in ACCEPTANCE:
        return _failure(problem, t0, f"acceptance must be one of {', '.join(ACCEPTANCE)}, got {acceptance!r}")
    if equality_rule not in EQUALITY_RULES:
        return _failure(problem, t0, f"equality_rule must be one of {', '.join(EQUALITY_RULES)}, "
                                     f"got {equality_rule!r}")
    new_factorizations = solver is None
    if solver is None:
        solver = FetiFetiSolver(problem.sub, problem.gi)
    # dualize (6.14) -> homogenize (6.16) -> enforce (6.17)
    dual = dualize(problem, solver)
    if isinstance(dual, str):
        return _failure(problem, t0, dual)
    homogeneous = homogenize(dual)
    if isinstance(homogeneous, str):
        return _failure(problem, t0, homogeneous)
    # absolute parameters in the units of F: the defaults follow its scale (F_scale = 1 for rho = 1)
    M = DEFAULT_M * dual.F_scale if M is None else M
    rho0 = DEFAULT_RHO0 * dual.F_scale if rho0 is None else rho0
    if isinstance(rho_bar, str) and rho_bar == RELATIVE:
        rho_bar = DEFAULT_RHO_BAR * dual.F_scale
    elif isinstance(rho_bar, str):
        return _failure(problem, t0, f"rho_bar must be a positive number, {RELATIVE!r} or None, got {rho_bar!r}")
    enforced = enforce(homogeneous, rho_bar)
    if isinstance(enforced, str):
        return _failure(problem, t0, enforced)
    rho_bar, norm_b, net = enforced.rho_bar, enforced.norm_b, dual.net_load
    n, n_local, n_contact = dual.n, dual.n_local, dual.n_contact
    setup = time.perf_counter() - t0
    log.info("SMALBE dual setup: n_lambda = %d (%d local + %d contact), ||PFP|| = %.4g (%d F-mults), "
             "lambda~ = %.4g", n, n_local, n_contact, enforced.norm_PFP, enforced.n_norm_estimate,
             homogeneous.lambda_tilde[-1])
    # solve (SMALBE/MPRGP)
    try:
        res, tol_eq = solve_enforced(enforced, eps=eps, M=M, rho0=rho0, Gamma=Gamma, maxiter=maxiter,
                                     max_outer=max_outer, equality_rule=equality_rule, halfstep=halfstep)
    except ValueError as exc:                                # invalid parameters: report, do not raise
        return _failure(problem, t0, f"invalid SMALBE input: {exc}")
    # map back: balanced multiplier P lambda + lambda~, primal recovery
    rec = map_back(enforced, res.x)
    u, lam_c, active, Gx = rec.u, rec.lam_contact, rec.active, rec.equality_defect
    seconds = time.perf_counter() - t0
    log.info("SMALBE dual (3.1): %s; %d outer, inner %s, %d active pairs of %d, %.3f s",
             res.reason, res.outer_iterations, res.inner_iterations, int(active.sum()), n_contact, seconds)
    extra = {
        "nlambda": n, "n_local": n_local, "n_contact": n_contact,
        "n_hessian": res.n_hessian, "n_cg": res.n_cg, "n_expansion": res.n_expansion,
        "n_proportioning": res.n_proportioning, "n_Fmult": dual.n_F[0], "n_norm_estimate": enforced.n_norm_estimate,
        "penalty": res.penalty, "rho_bar": rho_bar, "norm_PFP": enforced.norm_PFP, "alpha": res.alpha,
        "M": M, "rho0": rho0, "F_scale": dual.F_scale,
        "lambda_tilde": float(homogeneous.lambda_tilde[-1]), "mu": res.mu, "rigid_alpha": rec.rigid_alpha,
        "norm_b": norm_b, "norm_e": abs(dual.e), "tol_equality": tol_eq, "net_load": net,
        "gradient_norms": res.gradient_norms, "constraint_norms": res.constraint_norms,
        "local_jump": norm2(solver.B_loc @ rec.u_W),      # scaled: no overflow of the squares
        "equality_defect": Gx, "setup_seconds": setup, "qp_seconds": res.seconds,
        "lambda": rec.lambda_balanced, "u_unpolished": rec.u, "lambda_unpolished": rec.lam_contact,
    }
    # ||b|| as a force for the equality part of Section 6.4's rule (literally ||b|| under the thesis's rule)
    b_level = norm_b if equality_rule == "section-6.4" else norm_b / dual.F_scale
    converged, reason = _judge(problem, res, rec, enforced, eps, tol_eq, extra, enforce=acceptance == "enforce",
                               b_level=b_level)
    # the rule of Section 6.4 alone (||G lambda|| <= eps ||b||): met, but the contact force is not resolved
    gp_last = float(res.gradient_norms[-1]) if res.gradient_norms.size else math.inf
    section_64 = gp_last <= eps * norm_b and abs(Gx) <= eps * b_level
    rescue = polish == "auto" and not converged and (section_64 or res.converged)
    refine = polish == "auto" and converged
    if (polish is True and converged or rescue or refine) and active.any():
        kkt_smalbe = _residual(problem, u, lam_c)
        out = _polish(problem, solver, active, rec.lambda_balanced, n_local, eps, net, extra)
        if out is None and converged and extra.get("polish_wrong_set"):
            # the equality solve on SMALBE's active set needs a pulling multiplier: that set is not the
            # solution's, so neither is SMALBE's lambda (a review: checkerboard 1e-6, lambda 57% off, KKT
            # stationarity 18 eps, reported converged)
            converged = False
            reason = (f"not accepted: {reason.removeprefix('converged: ')}, but SMALBE's active set is not the "
                      f"solution's: the equality solve on it has a {extra['polish_reason']} (its lambda would pull)")
        elif out is None:
            reason = f"{reason}; polish on the active set rejected ({extra['polish_reason']})"
            # SMALBE's pair stays the answer, checked as without the polish (_verify) where the equality solve
            # converged (it penetrates off the set or fails the acceptance check; a review)
            converged, reason = _lambda_check(extra.pop("_polish_lambda", None), lam_c, eps, extra,
                                              "polish_lambda_change", converged, reason)
        elif polish == "auto" and not _residual(problem, *out) < kkt_smalbe:
            extra["polish"] = "rejected"
            reason = f"{reason}; polish on the active set rejected (KKT residual not lowered)"
            # SMALBE's pair stays the answer, checked as without the polish (_verify): its lambda must be
            # resolved on its own active set (a review: checkerboard 1e16, 4 x 4 subdomains, H/h = 2, lambda 41%
            # off with the KKT residuals, weighted penetration included, under the limit)
            converged, reason = _lambda_check(out[1], lam_c, eps, extra, "polish_lambda_change", converged, reason)
        else:
            u, lam_c = out
            active = lam_c > 0.0
            if rescue:
                converged = True
                # "not accepted" must not begin the reason of a converged result (docs/api.md)
                reason = (f"converged: rescued by a FETI-FETI solve on SMALBE's active set "
                          f"({extra['polish_iterations']} PCG iterations) that passes the KKT and force checks; "
                          f"SMALBE alone: {reason.removeprefix('not accepted: ')}")
            else:
                reason = (f"{reason}; polished on the active set in {extra['polish_iterations']} PCG "
                          f"iterations")
        _accept(problem, u, lam_c, net, eps, extra)             # residuals of what is returned
    # the KKT acceptance rule of every iterative contact solve (SMALBE's own checks read its stationarity
    # against eps, without the ceiling: at eps 0.5 a KKT residual of 0.93 passed them)
    kkt = problem.kkt(u, lam_c)
    converged, reason = kkt_verdict(converged, reason, kkt.max, eps)
    if polish is False and converged and acceptance == "enforce" and active.any():
        # after the cheap checks: one FETI-FETI solve, for an answer that passes all of them
        converged, reason = _verify(problem, solver, active, rec.lambda_balanced, lam_c, n_local, eps, net,
                                    extra, reason)
    seconds = time.perf_counter() - t0
    return ContactSolution(u=u, lam=lam_c, active=active, converged=converged, reason=reason,
                           outer_iterations=res.outer_iterations, inner_iterations=list(res.inner_iterations),
                           seconds=seconds,
                           n_factorizations=solver.n_factorizations if new_factorizations else 0,
                           extra=extra, kkt=kkt)


def _judge(problem: ContactProblem, res: QPResult, rec: RecoveredSolution, enforced: EnforcedProblem,
           eps: float, tol_eq: float | None, extra: dict, enforce: bool = True,
           b_level: float | None = None) -> tuple[bool, str]:
    """SMALBE's verdict, the note when only the rule of Section 6.4 is met, and the acceptance check.

    ``enforce=False``: a failed check is noted in the reason but leaves SMALBE's verdict.
    ``b_level``: the bound on ||G lambda|| of that rule over eps (default ||b||; the default
    rule passes ||b|| / F_scale, ||b|| in force units).
    """
    converged, reason = bool(res.converged), res.reason
    norm_b, Gx = enforced.norm_b, rec.equality_defect
    b_level = norm_b if b_level is None else b_level
    net = enforced.homogeneous.dual.net_load
    gp_last = float(res.gradient_norms[-1]) if res.gradient_norms.size else math.inf
    section_64 = gp_last <= eps * norm_b and abs(Gx) <= eps * b_level
    if not converged and section_64:
        reason = (f"SMALBE met the rule of Section 6.4 (||G lambda|| = {abs(Gx):.2e} <= eps ||b||) but not "
                  f"||G lambda|| <= eps ||e|| = {tol_eq or 0.0:.2e}: the contact force (net load {net:.3g}) "
                  f"is not resolved ({res.reason})")
    ok, why = _accept(problem, rec.u, rec.lam_contact, net, eps, extra)
    extra["acceptance"] = "passed" if ok else f"failed: {why}"
    if converged and not ok:
        if enforce:
            converged = False
            reason = f"not accepted: stopping rule met ({reason.removeprefix('converged: ')}) but acceptance check failed: {why}"
        else:
            reason = f"{reason}; acceptance check failed: {why}"
    return converged, reason


def _residual(problem: ContactProblem, u: np.ndarray, lam: np.ndarray) -> float:
    """The larger of the KKT residual (5.5) and the stiffness-weighted penetration of a pair: what the
    polish must lower to be kept."""
    return max(problem.kkt(u, lam).max, problem.weighted_feasibility(u))


def _accept(problem: ContactProblem, u: np.ndarray, lam: np.ndarray, net: float, eps: float,
            extra: dict) -> tuple[bool, str]:
    """A-posteriori acceptance check of a primal-dual pair (module docstring, "Acceptance check").

    Finite values, the equilibrium of the floating body Omega^2:
    ``|sum(lam) - net| <= FORCE_FACTOR eps net`` (net = -integral of f over Omega^2 > 0),
    and the KKT stationarity ``<= STATIONARITY_FACTOR eps``.
    Records ``force_error`` and ``kkt`` (the relative KKT residuals) in ``extra``.

    Returns
    -------
    (ok, why)
    """
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(lam))):
        extra["force_error"] = math.nan
        return False, "non-finite u or lambda"
    force = abs(float(lam.sum()) - net) / net
    extra["force_error"] = force
    kkt = problem.kkt(u, lam)
    extra["kkt"] = kkt.as_dict()
    if not force <= FORCE_FACTOR * eps:
        return False, (f"contact force sum(lambda) = {lam.sum():.6g} off the net load {net:.6g} on Omega^2 "
                       f"by {force:.1e} (> {FORCE_FACTOR:g} eps = {FORCE_FACTOR * eps:.1e})")
    if not kkt.stationarity <= STATIONARITY_FACTOR * eps:
        return False, (f"KKT stationarity ||Ku - f + B^T lambda|| / (||f|| + ||B^T lambda||) = "
                       f"{kkt.stationarity:.1e} > {STATIONARITY_FACTOR:g} eps = {STATIONARITY_FACTOR * eps:.1e}")
    # the penetration as a force (ContactProblem.weighted_feasibility): under coefficient jumps SMALBE can
    # stop with pairs in the wrong set whose penetration the KKT feasibility, relative to ||u||_inf, misses
    weighted = problem.weighted_feasibility(u)
    extra["kkt_weighted_feasibility"] = weighted
    if not weighted <= kkt_limit(eps):
        return False, (f"penetration weighted by the stiffness max (B u)_+ w / ||diag(K) u||_inf = "
                       f"{weighted:.1e} > {kkt_limit(eps):.1e} (pairs in the wrong set under a coefficient jump?)")
    return True, ""


def _polish(problem: ContactProblem, solver: FetiFetiSolver, active: np.ndarray, lam_bal: np.ndarray,
            n_loc: int, eps: float, net: float, extra: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """FETI-FETI solve (3.35) on SMALBE's active set, warm started; keep it only if it stays KKT-feasible.

    Sets ``extra["polish"]`` ("accepted" / "rejected"), ``extra["polish_iterations"]`` and, when
    rejected, ``extra["polish_reason"]``.

    Returns
    -------
    (u, lam_c) or None
        The polished solution (``lam_c`` >= 0, zero off the active set), or None when rejected.
    """
    lam0 = np.concatenate([lam_bal[:n_loc], lam_bal[n_loc:][active]])
    out = solver.solve(active, rtol=eps, maxiter=POLISH_MAXITER, lam0=lam0, check=False)   # judged by its KKT
    extra["polish_iterations"] = int(out.krylov.iterations)
    lam_p = np.zeros(problem.n_contact)
    lam_p[active] = out.extra["lambda_gl"]
    tol = 10.0 * eps
    gap = problem.gap(out.u)
    lam_c = np.where(active, np.maximum(lam_p, 0.0), 0.0)
    why = ""
    if not out.krylov.converged:
        why = f"PCG: {out.krylov.reason}"
    elif not lam_p[active].min() >= -tol * max(float(np.abs(lam_p).max()), 1e-300):
        why = f"negative multiplier {lam_p[active].min():.2e}"
        extra["polish_wrong_set"] = True
    elif not gap[~active].max(initial=-np.inf) <= tol * max(float(np.abs(out.u).max()), 1e-300):
        why = f"penetration {gap[~active].max(initial=-np.inf):.2e} off the active set"
    else:
        ok, why = _accept(problem, out.u, lam_c, net, eps, {})
        why = "" if ok else why
    if why:
        extra["polish"], extra["polish_reason"] = "rejected", why
        kr = out.krylov
        r0 = float(kr.residuals[0]) if len(kr.residuals) else math.nan
        reached = (kr.true_residual / r0 if kr.true_residual is not None and r0 > 0.0 else math.inf)
        if not extra.get("polish_wrong_set") and (kr.converged or reached <= LOOSE_POLISH_RESIDUAL):
            # resolved on the active set (to rtol, or to LOOSE_POLISH_RESIDUAL where rtol is below the attainable
            # accuracy): what _lambda_check compares with, then against LOOSE_LAMBDA_CHANGE at least
            extra["_polish_lambda"] = (lam_c, not kr.converged)
        return None
    extra["polish"] = "accepted"
    return out.u, lam_c


#: An equality solve on SMALBE's active set that stopped short of eps (eps below the attainable accuracy, at
#: extreme coefficient jumps) is still read by the lambda check if its recomputed relative residual is at most
#: this, with a limit of at least LOOSE_LAMBDA_CHANGE: at checkerboard 1e16 and eps 1e-10 SMALBE returned
#: lambda 41-59% off as converged, its polish "tolerance not attained" at 2e-6 (a review).
LOOSE_POLISH_RESIDUAL = 1e-4
LOOSE_LAMBDA_CHANGE = 1e-2


def _lambda_check(lam_p, lam_c: np.ndarray, eps: float, extra: dict, key: str,
                  converged: bool, reason: str) -> tuple[bool, str]:
    """A converged SMALBE pair returned as it is must have its lambda resolved on its own active set: not
    converged when ``lam_p`` (the equality solve on that set, :func:`_polish`) differs by more than
    :func:`~ddsolve.contact.problem.kkt_limit` (eps) of max |lam_p|. ``lam_p`` may be ``(lam, loose)``:
    with ``loose`` (that solve stopped short of eps, at most at :data:`LOOSE_POLISH_RESIDUAL`) the limit is
    at least :data:`LOOSE_LAMBDA_CHANGE`. ``extra[key]`` records the change; nothing is checked without
    ``lam_p``."""
    if lam_p is None:
        return converged, reason
    loose = False
    if isinstance(lam_p, tuple):
        lam_p, loose = lam_p
    limit = max(kkt_limit(eps), LOOSE_LAMBDA_CHANGE) if loose else kkt_limit(eps)
    change = float(np.abs(lam_p - lam_c).max()) / max(float(np.abs(lam_p).max()), 1e-300)
    extra[key] = change
    if converged and not change <= limit:
        return False, (f"not accepted: {reason.removeprefix('converged: ')}, but the equality solve on SMALBE's "
                       f"active set moves lambda by {change:.1e} of max |lambda| (> {limit:.1e}): SMALBE's lambda "
                       f"is not resolved")
    return converged, reason


def _verify(problem: ContactProblem, solver: FetiFetiSolver, active: np.ndarray, lam_bal: np.ndarray,
            lam_c: np.ndarray, n_loc: int, eps: float, net: float, extra: dict, reason: str) -> tuple[bool, str]:
    """Check of a converged SMALBE result that is returned unpolished (``polish=False``, the thesis preset).

    The FETI-FETI solve (3.35) on SMALBE's active set of :func:`_polish` is run, but only its multipliers
    are read: SMALBE's own pair stays the answer. The result is not converged when that solve needs a
    pulling multiplier (the active set is not the solution's, as under ``polish="auto"``) or when its
    multipliers differ from SMALBE's by more than :func:`~ddsolve.contact.problem.kkt_limit` (eps) relative
    to max |lambda|: SMALBE's lambda is then not resolved on its own active set. Under a checkerboard of
    1e8 on 4 x 4 subdomains (H/h = 8, eps = 1e-6) SMALBE stopped by Section 6.4's rule with KKT residuals
    of 5e-6 and lambda 38% off (against the active set method and the direct solver, which agree to
    1e-10), reported converged; the equality solve on its active set moves lambda by as much. A check
    that cannot be made (the solve does not converge in ``POLISH_MAXITER`` iterations, or it penetrates
    off the active set) leaves the verdict and says so in ``extra["verify"]``.

    Sets ``extra["verify"]`` ("passed", "failed: ..." or "not made: ..."), ``extra["verify_iterations"]``
    and, when the solve is kept, ``extra["verify_lambda_change"]``.

    Returns
    -------
    (converged, reason)
    """
    scratch: dict = {}
    out = _polish(problem, solver, active, lam_bal, n_loc, eps, net, scratch)
    extra["verify_iterations"] = scratch["polish_iterations"]
    limit = kkt_limit(eps)
    stripped = reason.removeprefix("converged: ")
    if out is None:
        why = scratch["polish_reason"]
        if scratch.get("polish_wrong_set"):
            extra["verify"] = f"failed: {why}"
            return False, (f"not accepted: {stripped}, but SMALBE's active set is not the solution's: the "
                           f"equality solve on it has a {why} (its lambda would pull)")
        lam_p = scratch.pop("_polish_lambda", None)
        if lam_p is None:
            extra["verify"] = f"not made: {why}"
            return True, reason
        # the equality solve converged but penetrates off the set or fails the acceptance check: its lambda
        # still tells whether SMALBE's is resolved on that set (a review: checkerboard 1e16, rtol 1e-3, 41% off)
        ok, reason = _lambda_check(lam_p, lam_c, eps, extra, "verify_lambda_change", True, reason)
        extra["verify"] = ("passed" if ok else f"failed: lambda change {extra['verify_lambda_change']:.1e}") + \
            f" (the equality solve: {why})"
        return ok, reason
    ok, reason = _lambda_check(out[1], lam_c, eps, extra, "verify_lambda_change", True, reason)
    extra["verify"] = "passed" if ok else f"failed: lambda change {extra['verify_lambda_change']:.1e} > {limit:.1e}"
    return ok, reason


def _failure(problem: ContactProblem, t0: float, reason: str) -> ContactSolution:
    """Non-converged result with zero iterates (data that (6.17) cannot handle)."""
    log.warning("SMALBE dual (3.1) not run: %s", reason)
    return ContactSolution(u=np.zeros(problem.ndof), lam=np.zeros(problem.n_contact),
                           active=np.zeros(problem.n_contact, dtype=bool), converged=False, reason=reason,
                           seconds=time.perf_counter() - t0)
