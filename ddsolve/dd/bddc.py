"""BDDC with primal subdomain vertices (Section 2.7)."""
from __future__ import annotations

import time

import numpy as np

from ..krylov import pcg
from .common import MethodOutput
from .operators import DirichletSchur, PrimalConstrainedSolver, linear_operator
from .substructure import Substructures


def solve_bddc(sub: Substructures, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False) -> MethodOutput:
    """BDDC: PCG on S^_Gamma u_Gamma = g (2.25) with M^{-1} = R_D^T S~^{-1} R_D (2.27).

    * S^_Gamma = R^T S R applied with local Schur complements (2.26);
    * S~^{-1} applied through A~^{-1} of (2.17) with zero interior load;
    * R_D: delta-dagger scaling on the dual nodes, the primal value unchanged
      (weights of the copies of a primal node sum to one);
    * interior values by discrete harmonic extension u_I = A_II^{-1}(f_I - A_IG u_G).

    Parameters
    ----------
    sub : Substructures
    rtol, maxiter : float, int
        Stopping rule ||r_k|| / ||r_0|| < rtol.
    cond : bool
        Lanczos estimate of the condition number of M^{-1} S^_Gamma.

    Returns
    -------
    MethodOutput
    """
    t0 = time.perf_counter()
    cache: dict = {}
    gamma_mask = sub.interface
    schur = DirichletSchur(sub, gamma_mask, cache)
    primal_solver = PrimalConstrainedSolver(sub, sub.vertex, cache)
    gamma_entries = np.flatnonzero(gamma_mask)
    dofs = np.unique(sub.l2g[gamma_entries])
    n_g = dofs.size
    gamma_pos = np.searchsorted(dofs, sub.l2g[gamma_entries])    # global interface index of each Gamma entry
    delta_g = sub.delta[gamma_entries]

    def scatter(u_g: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        w = np.zeros(sub.n_W)
        w[gamma_entries] = u_g[gamma_pos] if weights is None else weights * u_g[gamma_pos]
        return w

    def gather(w: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        vals = w[gamma_entries] if weights is None else weights * w[gamma_entries]
        return np.bincount(gamma_pos, weights=vals, minlength=n_g)

    def S_hat(u_g: np.ndarray) -> np.ndarray:
        return gather(schur.matvec(scatter(u_g)))

    def M(r_g: np.ndarray) -> np.ndarray:
        x = primal_solver.solve(scatter(r_g, delta_g))
        return gather(x, delta_g)

    g = gather(schur.harmonic_extension_rhs(sub.f_W))
    setup = time.perf_counter() - t0
    kr = pcg(linear_operator(n_g, S_hat), g, None, rtol=rtol, maxiter=maxiter,
             M=linear_operator(n_g, M), cond=cond)
    u_W = schur.interior_solution(sub.f_W, scatter(kr.x))
    return MethodOutput(u=sub.average(u_W), krylov=kr, nlambda=0,
                        n_factorizations=primal_solver.n_factorizations + schur.II.n_new_factorizations,
                        setup_seconds=setup, extra={"n_primal": primal_solver.n_primal, "n_interface": int(n_g)})
