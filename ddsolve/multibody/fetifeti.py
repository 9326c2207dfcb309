"""The FETI-FETI method (Section 3.4).

FETI-DP structure inside each body (every subdomain vertex of a body is
primal, including the ends of local edges on the body's boundary), dual
multipliers B_loc inside bodies and B_gl between bodies (fully redundant at
cross points), of which only the rows selected by the active mask Z^k are
used, (3.33)-(3.35). The dual problem

    Z B~_c A~_c^+ B~_c^T Z lambda = Z B~_c A~_c^+ f~_c

is solved by projected PCG with the preconditioner
M_D^{-1} = Z B~_{D,c} S~ B~_{D,c}^T Z and, for floating bodies, the natural
coarse space G = Z B~_c R (R: constants on each floating body), exactly as
one-level FETI treats floating subdomains (2.13)-(2.14).
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..dd.common import MethodOutput
from ..dd.dual import dual_operators, projection_weights, solve_dual
from ..dd.operators import DirichletSchur, PrimalConstrainedSolver
from ..dd.projection import gram_is_singular
from ..dd.substructure import Substructures
from ..errors import InputError, check_flag, check_tolerance
from .check import checked_output
from .interface import UNTIED_MESSAGE, UNTIED_TOL, GlobalInterface


class FetiFetiSolver:
    """FETI-FETI operators of one multibody scene; the active mask is an input of :meth:`solve`.

    All subdomain factorizations (A_rr per shared class, the coarse problem of
    each body with one pinned vertex per floating body, Dirichlet solves) are
    computed once in the constructor and reused for every active mask.

    Parameters
    ----------
    sub : Substructures
        Layout of a multibody scene.
    gi : GlobalInterface
        Its inter-body multipliers.
    """

    def __init__(self, sub: Substructures, gi: GlobalInterface) -> None:
        t0 = time.perf_counter()
        self.sub, self.gi = sub, gi
        cache: dict = {}
        self.floating = gi.floating_bodies()
        self.primal_solver = PrimalConstrainedSolver(sub, sub.vertex, cache, fixed_bodies=self.floating)
        self.B_loc, self.B_loc_D = sub.jump_operators(sub.interface & ~sub.vertex)
        self.schur = DirichletSchur(sub, sub.interface | gi.mask, cache)
        self.n_factorizations = self.primal_solver.n_factorizations + self.schur.II.n_new_factorizations
        # representative copy of every entry: primal copies -> designated (first) copy of the node
        first = np.full(sub.scene.n_nodes, -1)
        nodes, idx = np.unique(sub.node_of_W, return_index=True)
        first[nodes] = idx
        self.representative = np.where(sub.vertex, first[sub.node_of_W], np.arange(sub.n_W))
        # kernel: constants on every W entry of each floating body
        body = sub.body_of_sub[sub.sub_of_W]
        col = np.full(sub.scene.n_bodies, -1)
        col[self.floating] = np.arange(self.floating.size)
        ent = np.flatnonzero(col[body] >= 0)
        self.R = sp.csr_matrix((np.ones(ent.size), (ent, col[body[ent]])), shape=(sub.n_W, self.floating.size))
        self.d_full = self.primal_solver.solve(sub.f_W)
        self.setup_seconds = time.perf_counter() - t0

    def _tilde_schur(self, w: np.ndarray) -> np.ndarray:
        """S~ w on W~_Gamma: copy primal values to all subdomain copies, apply S, sum the copies back."""
        y = self.schur.matvec(w[self.representative])
        return np.bincount(self.representative, weights=y, minlength=self.sub.n_W)

    def solve(self, active: np.ndarray, *, rtol: float = 1e-6, maxiter: int = 1000, cond: bool = False,
              lam0: np.ndarray | None = None, projection: str = "weighted",
              check: bool | None = None) -> MethodOutput:
        """Solve (3.35) on the active set Z^k.

        Parameters
        ----------
        active : ndarray of bool, shape (gi.n_gl,)
            Diagonal of Z_gl^k.
        rtol, maxiter, cond : see :func:`ddsolve.krylov.pcg`.
        lam0 : ndarray, optional
            Warm start (local multipliers first, then the active global ones).
        projection : {"weighted", "orthogonal"}
            Q-weighted projection under rho-scaling (default, as in one-level FETI) or
            the orthogonal P = I - G (G^T G)^{-1} G^T of (2.13) (the thesis preset).
        check : bool, optional
            The final error check (:func:`ddsolve.multibody.check.checked_output`): None (default) where
            rho varies between subdomains or the mesh is unstructured, True always, False never.

        Returns
        -------
        MethodOutput
            ``extra["lambda_gl"]``: multipliers of the active global pairs; ``extra["error_estimate"]``
            where the check ran (above its limit the result is not converged).
        """
        rtol, cond = check_tolerance("rtol", rtol), check_flag("cond", cond)
        active = self.gi.active_mask(active)
        t0 = time.perf_counter()
        sub = self.sub
        B_gl, B_gl_D = self.gi.operators(active)
        B = sp.vstack([self.B_loc, B_gl]).tocsr()
        B_D = sp.vstack([self.B_loc_D, B_gl_D]).tocsr()
        BT = B.T.tocsr()

        F, M = dual_operators(B, B_D, self.primal_solver.solve, self._tilde_schur)
        d = B @ self.d_full
        G = e = None
        if self.floating.size:
            G = (B @ self.R).tocsc()
            e = self.R.T @ sub.f_W
            # G^T lambda = e must be solvable: every floating body tied to a clamped one through the active
            # pairs, as the hybrid method checks (HybridSolver.active_set). solve_dual's sparse LU does not
            # check it (a review: four floating bodies tied only to each other gave converged=True with
            # G^T lambda - e 25% of ||e||; no active pair at all, "Factor is exactly singular").
            if gram_is_singular(G, UNTIED_TOL):                 # the test of HybridSolver's projection
                raise InputError("active", UNTIED_MESSAGE)
        q = projection_weights(B_D, sub.rho[sub.sub_of_W], sub.scaling, projection)
        setup = time.perf_counter() - t0
        if lam0 is not None and np.shape(lam0) != (B.shape[0],):
            raise InputError("lam0", f"must have shape ({B.shape[0]},) (the local multipliers, then the "
                                     f"{B_gl.shape[0]} active global ones), got {np.shape(lam0)}")
        sol = solve_dual(F, M, d, G, e, q, rtol=rtol, maxiter=maxiter, cond=cond, lam0=lam0)
        u_W = self.primal_solver.solve(sub.f_W - BT @ sol.lam)
        if sol.alpha is not None:
            u_W = u_W + self.R @ sol.alpha
        n_loc = self.B_loc.shape[0]
        out = MethodOutput(u=sub.average(u_W), krylov=sol.krylov, nlambda=B.shape[0],
                           n_factorizations=self.n_factorizations, setup_seconds=self.setup_seconds + setup,
                           extra={"n_floating_bodies": int(self.floating.size),
                                  "lambda_gl": sol.lam[n_loc:], "lambda": sol.lam})
        return checked_output(out, self.gi, active, rtol, "feti-feti", check)
