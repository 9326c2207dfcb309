"""One-level FETI with the Dirichlet preconditioner (Section 2.5)."""
from __future__ import annotations

import time

import numpy as np

from ..errors import check_flag, check_tolerance
from .check import energy_error_estimate, judge_output, needs_check
from .common import MethodOutput
from .dual import dual_operators, projection_weights, solve_dual
from .local import BatchedSolver
from .operators import DirichletSchur, PrimalConstrainedSolver
from .substructure import Substructures


def pinned_entries(sub) -> np.ndarray:
    """W entries fixed by the generalized inverse A^+ of one-level FETI: the middle local node of
    every floating subdomain, as a mask of shape (n_W,) (one vectorized pass, no loop over subdomains)."""
    fixed = np.zeros(sub.n_W, dtype=bool)
    s = np.flatnonzero(sub.floating_sub)
    lo, hi = np.asarray(sub.offsets)[s], np.asarray(sub.offsets)[s + 1]
    fixed[lo + (hi - lo) // 2] = True
    return fixed


def solve_feti(sub: Substructures, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
               projection: str = "weighted") -> MethodOutput:
    """One-level FETI: PCG on P F lambda = P d, lambda in lambda_0 + V (2.14).

    * F = B A^+ B^T, d = B A^+ f with a generalized inverse A^+ of each
      floating subdomain matrix (one node fixed, which satisfies A A^+ A = A);
    * G = B R with R the constants on floating subdomains, e = R^T f,
      P = I - G (G^T G)^{-1} G^T and lambda_0 = G (G^T G)^{-1} e so that
      G^T lambda_0 = e (2.13);
    * Dirichlet preconditioner M_D^{-1} = B_D S B_D^T (Section 2.5);
    * u = A^+ (f - B^T lambda) + R alpha, alpha = (G^T G)^{-1} G^T (F lambda - d).

    Coefficient jumps. The orthogonal projection of (2.13) is not robust when
    rho jumps between floating subdomains (the largest eigenvalue grows with
    the jump). With rho-scaling we therefore use the Q-weighted projection
    P_Q = I - Q G (G^T Q G)^{-1} G^T of Klawonn and Widlund, with the diagonal
    Q = diag(B_D diag(rho) B_D^T) (for gamma = 1 the entry of the multiplier
    between subdomains i and j is rho_i rho_j / (rho_i + rho_j)). It is applied
    as the orthogonal projection of the similar system in mu = Q^{-1/2} lambda,
    so PCG and the residual norms act on mu. With multiplicity scaling Q = I,
    which is exactly (2.13)-(2.14). ``projection="orthogonal"`` takes Q = I under
    rho-scaling too (the thesis's P of (2.13); the thesis preset).

    Without floating subdomains there is no kernel: P, G and lambda_0 are skipped.

    Parameters
    ----------
    sub : Substructures
    rtol, maxiter : float, int
        Stopping rule ||r_k|| / ||r_0|| < rtol.
    cond : bool
        Lanczos estimate of the condition number of P M_D^{-1} P F.
    projection : {"weighted", "orthogonal"}
        Q-weighted P under rho-scaling (default) or the orthogonal P of (2.13).

    Returns
    -------
    MethodOutput
    """
    rtol, cond = check_tolerance("rtol", rtol), check_flag("cond", cond)
    t0 = time.perf_counter()
    cache: dict = {}
    B, B_D = sub.jump_operators(np.ones(sub.n_W, dtype=bool))
    fixed = pinned_entries(sub)
    Kplus = BatchedSolver(sub, ~fixed, cache)
    schur = DirichletSchur(sub, sub.interface, cache)
    n_lam = B.shape[0]

    F, M = dual_operators(B, B_D, Kplus.solve, schur.matvec)
    d = B @ Kplus.solve(sub.f_W)
    n_fact = Kplus.n_new_factorizations + schur.II.n_new_factorizations
    R = G = e = None
    if sub.floating_sub.any():
        R = sub.kernel_basis()
        G = (B @ R).tocsc()
        e = R.T @ sub.f_W
        n_fact += 1
    q = projection_weights(B_D, sub.rho[sub.sub_of_W], sub.scaling, projection)
    setup = time.perf_counter() - t0

    sol = solve_dual(F, M, d, G, e, q, rtol=rtol, maxiter=maxiter, cond=cond)
    kr = sol.krylov
    u_W = Kplus.solve(sub.f_W - B.T @ sol.lam)
    if sol.alpha is not None:
        u_W = u_W + R @ sol.alpha
    u = sub.average(u_W)
    extra = {"n_floating": int(sub.floating_sub.sum())}
    if kr.converged and needs_check(sub.rho, sub.templates, rtol):    # the dual rule bounds the jump B u, not the error of u
        primal_solver = PrimalConstrainedSolver(sub, sub.vertex, cache)     # one more factorization
        extra["error_estimate"] = energy_error_estimate(sub, u, primal_solver, schur)
        n_fact += primal_solver.n_factorizations
    return judge_output(MethodOutput(u=u, krylov=kr, nlambda=n_lam, n_factorizations=n_fact,
                                     setup_seconds=setup, extra=extra), rtol, "feti")
