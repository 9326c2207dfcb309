"""The persistent operators of DDInverse's three methods on an NGSolve form's subdomains.

Everything that does not depend on the right-hand side is built once (factorizations, coarse
problems, projections); each class's ``solve(f_W, rtol, maxiter, cond)`` is one Krylov solve on
the W load f_W and returns (u_W, KrylovResult). :class:`_BDDC` also gives the full-space BDDC
preconditioner (:meth:`_BDDC.precondition`) used by ``DDInverse.preconditioner`` and by its final
error estimate.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..dd import Substructures
from ..dd.deluxe import DeluxeScaling, deluxe_scaling
from ..dd.dual import dual_operators, projection_weights
from ..dd.local import BatchedSolver
from ..dd.operators import DirichletSchur, PrimalConstrainedSolver, linear_operator
from ..dd.projection import Projection
from ..errors import InputError
from ..krylov import KrylovResult, pcg
from ..scene.scene import sorted_unique


def _no_interface() -> KrylovResult:
    return KrylovResult.solved_directly(0, "interface")


class _BDDC:
    """Persistent BDDC operators on the interface (Section 2.7), as in :func:`ddsolve.dd.solve_bddc`."""

    def __init__(self, sub: Substructures, deluxe: bool = False) -> None:
        cache: dict = {}
        self.sub = sub
        self.schur = DirichletSchur(sub, sub.interface, cache)
        self.primal = PrimalConstrainedSolver(sub, sub.vertex, cache)
        self.primal.assemble_basis()
        ge = np.flatnonzero(sub.interface)
        dofs = sorted_unique(sub.l2g[ge])
        self.n_g = dofs.size
        self.ge, self.gpos, self.delta_g = ge, np.searchsorted(dofs, sub.l2g[ge]), sub.delta[ge]
        self.S_hat = linear_operator(self.n_g, lambda u: self.gather(self.schur.matvec(self.scatter(u))))
        self.M = linear_operator(self.n_g, self._M)
        self.deluxe: DeluxeScaling | None = None
        if deluxe and self.n_g:
            self.deluxe = deluxe_scaling(sub, self.schur.explicit_blocks(), sub.interface & ~sub.vertex, sub.delta)
            self._DT = self.deluxe.D.T.tocsr()

    @property
    def R(self) -> sp.csr_matrix:
        """The 0/1 scatter of interface values to their W copies, shape (n_W, n_g)."""
        return sp.csr_matrix((np.ones(self.ge.size), (self.ge, self.gpos)), shape=(self.sub.n_W, self.n_g))

    def scatter(self, u: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        w = np.zeros(self.sub.n_W)
        w[self.ge] = u[self.gpos] if weights is None else weights * u[self.gpos]
        return w

    def gather(self, w: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        v = w[self.ge] if weights is None else weights * w[self.ge]
        return np.bincount(self.gpos, weights=v, minlength=self.n_g)

    def _M(self, r: np.ndarray) -> np.ndarray:
        """M^{-1} r = R_D^T Ã^{-1} R_D r: R_D = D^T R (deluxe, :mod:`ddsolve.dd.deluxe`) or delta R."""
        if self.deluxe is not None:
            return self.gather(self.deluxe.D @ self.primal.solve(self._DT @ self.scatter(r)))
        return self.gather(self.primal.solve(self.scatter(r, self.delta_g)), self.delta_g)

    def solve(self, f_W: np.ndarray, rtol: float, maxiter: int, cond: bool):
        if self.n_g == 0:           # one subdomain: no interface, the interior solve is the answer
            return self.schur.interior_solution(f_W, np.zeros(self.sub.n_W)), _no_interface()
        g = self.gather(self.schur.harmonic_extension_rhs(f_W))
        kr = pcg(self.S_hat, g, None, rtol=rtol, maxiter=maxiter, M=self.M, cond=cond)
        return self.schur.interior_solution(f_W, self.scatter(kr.x)), kr

    def precondition(self, f_W: np.ndarray) -> np.ndarray:
        """One BDDC application in the full space: H M H^T + blockdiag(A_II^{-1})."""
        if self.n_g == 0:
            return self.schur.interior_solution(f_W, np.zeros(self.sub.n_W))
        g = self.gather(self.schur.harmonic_extension_rhs(f_W))
        return self.schur.interior_solution(f_W, self.scatter(self._M(g)))


class _FETIDP:
    """Persistent FETI-DP operators (Section 2.6), as in :func:`ddsolve.dd.solve_fetidp`."""

    def __init__(self, sub: Substructures, bddc: _BDDC) -> None:
        self.B, B_D = sub.jump_operators(sub.interface & ~sub.vertex)
        if bddc.deluxe is not None:
            B_D = bddc.deluxe.jump(self.B, B_D, bddc.R)
        self._B_D = B_D
        self.primal = bddc.primal
        self.BT = self.B.T.tocsr()
        F, M = dual_operators(self.B, B_D, self.primal.solve, bddc.schur.matvec)
        n = self.B.shape[0]
        self.F, self.M = linear_operator(n, F), linear_operator(n, M)

    def solve(self, f_W: np.ndarray, rtol: float, maxiter: int, cond: bool):
        if self.B.shape[0] == 0:    # no dual interface: A~ is the assembled matrix
            return self.primal.solve(f_W), _no_interface()
        d = self.B @ self.primal.solve(f_W)
        kr = pcg(self.F, d, None, rtol=rtol, maxiter=maxiter, M=self.M, cond=cond)
        return self.primal.solve(f_W - self.BT @ kr.x), kr


class _FETI:
    """Persistent one-level FETI operators (Section 2.5), as in :func:`ddsolve.dd.solve_feti`.

    Everything that does not depend on the right-hand side is built once: the
    generalized inverse A^+ (one node fixed per floating subdomain), the
    Dirichlet preconditioner (the Schur operator of ``bddc``), G = B R and the
    projection P of (2.13) (its factorization of G^T Q G). A solve is projected
    PCG on P F lambda = P d (2.14) with the Q-weighted projection of
    :func:`ddsolve.dd.dual.solve_dual`.
    """

    def __init__(self, sub: Substructures, bddc: _BDDC, vertex_W: np.ndarray, projection: str = "weighted") -> None:
        self.sub = sub
        self.B, B_D = sub.jump_operators(np.ones(sub.n_W, dtype=bool))
        self.BT = self.B.T.tocsr()
        # generalized inverse: fix one vertex dof (the constants live on the vertex dofs of a
        # hierarchical basis; fixing an edge dof would leave the kernel) of every floating part
        floating = np.flatnonzero(sub.floating_sub)
        candidates = np.flatnonzero(vertex_W & sub.floating_sub[sub.sub_of_W])
        first = np.searchsorted(sub.sub_of_W[candidates], floating)
        count = np.searchsorted(sub.sub_of_W[candidates], floating, side="right") - first
        if np.any(count == 0):
            raise InputError("method", "a floating part has no vertex dof; one-level FETI cannot pin it")
        fixed = np.zeros(sub.n_W, dtype=bool)
        fixed[candidates[first + count // 2]] = True
        self.Kplus = BatchedSolver(sub, ~fixed, {})
        F, M = dual_operators(self.B, B_D, self.Kplus.solve, bddc.schur.matvec)
        n = self.B.shape[0]
        q = projection_weights(B_D, sub.rho[sub.sub_of_W], sub.scaling, projection)
        self.sq = sq = np.ones(n) if q is None else np.sqrt(q)
        self.F = linear_operator(n, lambda mu: sq * F(sq * mu))
        self.M = linear_operator(n, lambda mu: M(mu / sq) / sq)
        self.R = self.projection = self.P = None
        if floating.size:
            # R: orthonormal constants (1 on the vertex dofs) of every floating part, shape (n_W, n_floating)
            col = np.full(sub.n_sub, -1)
            col[floating] = np.arange(floating.size)
            entries = np.flatnonzero(vertex_W & sub.floating_sub[sub.sub_of_W])
            size = np.bincount(sub.sub_of_W[entries], minlength=sub.n_sub)
            self.R = sp.csr_matrix((1.0 / np.sqrt(size[sub.sub_of_W[entries]]), (entries, col[sub.sub_of_W[entries]])),
                                   shape=(sub.n_W, floating.size))
            self.projection = Projection((sp.diags(sq) @ (self.B @ self.R)).tocsc(), sparse=True)
            self.P = linear_operator(n, self.projection.apply)

    def solve(self, f_W: np.ndarray, rtol: float, maxiter: int, cond: bool):
        sq = self.sq
        d = sq * (self.B @ self.Kplus.solve(f_W))
        mu0 = np.zeros(d.size)
        if self.projection is not None:
            mu0 = self.projection.particular(self.R.T @ f_W)
        kr = pcg(self.F, d, mu0, rtol=rtol, maxiter=maxiter, M=self.M, P=self.P, cond=cond)
        u_W = self.Kplus.solve(f_W - self.BT @ (sq * kr.x))
        if self.projection is not None:
            u_W = u_W + self.R @ self.projection.coefficients(self.F.matvec(kr.x) - d)
        return self.sub.restrict(self.sub.average(u_W)), kr
