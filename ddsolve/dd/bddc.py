"""BDDC with primal subdomain vertices (Section 2.7), optionally edge averages (:mod:`.edges`)."""
from __future__ import annotations

import time

import numpy as np

from ..errors import check_flag, check_tolerance
from ..krylov import KrylovResult, pcg
from .common import MethodOutput
from .operators import DirichletSchur, PrimalConstrainedSolver, linear_operator
from .substructure import Substructures



class InterfaceMap:
    """The interface space of BDDC: one value per interface dof, and its maps to and from W.

    Parameters
    ----------
    sub : Substructures
    gamma_mask : ndarray of bool, shape (n_W,)
        The interface entries of W.

    Attributes
    ----------
    dofs : ndarray, shape (n,)
        Global dof numbers of the interface, sorted.
    delta : ndarray
        The delta-dagger weights of the interface entries of W.
    """

    def __init__(self, sub, gamma_mask: np.ndarray) -> None:
        self.n_W = sub.n_W
        self.entries = np.flatnonzero(gamma_mask)
        self.dofs = np.unique(sub.l2g[self.entries])
        self.n = int(self.dofs.size)
        self.position = np.searchsorted(self.dofs, sub.l2g[self.entries])  # interface index of each entry
        self.delta = sub.delta[self.entries]

    def scatter(self, u_g: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        """R^T (weighted): interface values, shape (n,), to a W vector, shape (n_W,)."""
        w = np.zeros(self.n_W)
        w[self.entries] = u_g[self.position] if weights is None else weights * u_g[self.position]
        return w

    def gather(self, w: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        """R (weighted): the sum of the W entries of each interface dof, shape (n,)."""
        vals = w[self.entries] if weights is None else weights * w[self.entries]
        return np.bincount(self.position, weights=vals, minlength=self.n)


def solve_bddc(sub: Substructures, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False) -> MethodOutput:
    """BDDC: PCG on S^_Gamma u_Gamma = g (2.25) with M^{-1} = R_D^T S~^{-1} R_D (2.27).

    * S^_Gamma = R^T S R applied with local Schur complements (2.26);
    * S~^{-1} applied through A~^{-1} of (2.17) with zero interior load;
    * R_D: delta-dagger scaling on the dual nodes, the primal value unchanged
      (weights of the copies of a primal node sum to one);
    * interior values by discrete harmonic extension u_I = A_II^{-1}(f_I - A_IG u_G).

    With ``sub.primal == "vertices+edges"`` all of this runs in the basis of
    :meth:`Substructures.primal_space` (edge averages primal): f^ = T^T f,
    u = T u^ (the interface values u_Gamma are then in the new basis).

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
    rtol, cond = check_tolerance("rtol", rtol), check_flag("cond", cond)
    t0 = time.perf_counter()
    cache: dict = {}
    space = sub.primal_space()
    hat = space.sub                  # sub itself, or its copy in the edge-average basis
    f_W = space.to_primal(sub.f_W)
    gamma_mask = hat.interface
    schur = DirichletSchur(hat, gamma_mask, cache)
    schur.explicit                                      # decided (dense blocks formed) in the setup
    primal_solver = PrimalConstrainedSolver(hat, hat.vertex, cache)
    primal_solver.assemble_basis()                      # in the setup, not in the first solve
    iface = InterfaceMap(hat, gamma_mask)
    scatter, gather, delta_g, n_g = iface.scatter, iface.gather, iface.delta, iface.n
    def S_hat(u_g: np.ndarray) -> np.ndarray:
        return gather(schur.matvec(scatter(u_g)))

    def M(r_g: np.ndarray) -> np.ndarray:
        x = primal_solver.solve(scatter(r_g, delta_g))
        return gather(x, delta_g)

    g = gather(schur.harmonic_extension_rhs(f_W))
    setup = time.perf_counter() - t0
    if n_g == 0:            # every interface node primal, or no interface (a tiny mesh): nothing to iterate
        kr = KrylovResult.solved_directly(0, "interface unknowns")
    else:
        kr = pcg(linear_operator(n_g, S_hat), g, None, rtol=rtol, maxiter=maxiter,
                 M=linear_operator(n_g, M), cond=cond)
    u_W = space.from_primal(schur.interior_solution(f_W, scatter(kr.x)))
    return MethodOutput(u=sub.average(u_W), krylov=kr, nlambda=0,
                        n_factorizations=primal_solver.n_factorizations + schur.II.n_new_factorizations,
                        setup_seconds=setup, extra={"n_primal": primal_solver.n_primal, "n_interface": int(n_g)})
