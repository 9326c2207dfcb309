"""The hybrid method of Section 4.2 of Lee (2009): PCR on the KKT system (4.5).

Unknowns are the body-continuous interface values u_Gamma in
W^_{Gamma,c} = prod_i W^_Gamma^(i) (continuous across the local interface of
each body, one copy per body on the global interface) and the Lagrange
multipliers lambda on the active part of the global interface (the mask Z^k).
The saddle-point system (4.2),

    [ S^_c          (Z B^_{Gamma,c})^T ] [u_Gamma]   [g^_c]
    [ Z B^_{Gamma,c}        0          ] [lambda ] = [ 0  ],

is rewritten on range(S^_c) x V^k, V^k = ker(G^kT), G^k = Z B^_{Gamma,c} R_c,
as (4.5) with lambda = lambda_0 + mu, G^kT lambda_0 = e = R_c^T g^_c, and
solved by the preconditioned conjugate residual method with the block-diagonal
preconditioner (4.11)

    B^{-1} = diag(P_R M_BDDC^{-1} P_R,  P^k M_D^{-1} P^k),

where M_BDDC^{-1} is the BDDC preconditioner of every body (subdomains coupled
at their primal vertices, a generalized inverse on floating bodies) and
M_D^{-1} = Z B_{Gamma_OL,D} S~_OL B_{Gamma_OL,D}^T Z is the one-level FETI
Dirichlet preconditioner that regards each body as one subdomain, with the
inexact Schur complement S~_OL built on the inexact Dirichlet solver
(4.9)-(4.10).

Two options leave the thesis's method (the defaults) for robustness against
coefficient jumps on floating bodies (:meth:`HybridSolver.solve`): the PCR
stopping rule in ||r||_B = <r, B^{-1} r>^{1/2} instead of ||r||_2
(``norm="M"``), and FETI's Q-weighted projection P = I - QG(G^T Q G)^{-1} G^T,
Q = M_D^{-1} or its super-lumped diagonal, in place of the orthogonal P^k
(``projection="dirichlet"`` / ``"lumped"``).

Everything that needs a factorization (interior Dirichlet solves, the two
primal-constrained solvers and their coarse problems) is built once in
:class:`HybridSolver`; the active set only enters through index masks and the
small dense matrix G^kT G^k.
"""
from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..dd.common import MethodOutput
from ..dd.operators import DirichletSchur, PairJump, PrimalConstrainedSolver, linear_operator, scaled_jump
from ..dd.projection import Projection
from ..dd.substructure import Substructures
from ..errors import InputError, check_flag, check_tolerance
from ..krylov import PCR
from ..krylov.pcr import NORMS
from ..krylov.result import KrylovResult
from .check import checked_output
from .interface import UNTIED_MESSAGE, UNTIED_TOL, GlobalInterface
from .kernel import FloatingSums
from .spaces import ActiveSet, InterfaceSpace

log = logging.getLogger(__name__)

__all__ = ["ActiveSet", "HybridSolver", "InterfaceSpace", "PROJECTIONS", "NORMS", "RTOL_RULES", "S_OL_FORMS"]

#: Logged when a hybrid solve is asked for a condition estimate (``cond=True``): it has none.
NO_COND_MESSAGE = ("cond: the hybrid method's PCR computes no Lanczos estimate (Section 1.3), so cond stays None; "
                   "FETI-FETI (--method feti-feti) has one")

#: Stopping rules of a face solve: ||r_n|| <= rtol max(||r_0||, ||F_k||) (default) or rtol ||r_0|| (Section 4.4).
RTOL_RULES: tuple[str, ...] = ("max", "initial")
#: Forms of the inexact body Schur complement S~_OL in M_D^{-1} of (4.11): ``"thesis"``
#: S_GG - S_G0 M_0 S_0G of (4.9)-(4.10) (default), ``"energy"`` the PSD E^T S E (:meth:`HybridSolver.S_ol_energy`).
S_OL_FORMS: tuple[str, ...] = ("thesis", "energy")

#: Projections onto V^k = ker(G^kT): ``"orthogonal"`` is P^k of Section 4.2;
#: ``"dirichlet"`` and ``"lumped"`` are Q-weighted (FETI's P = I - QG(G^T Q G)^{-1} G^T)
#: with Q = M_D^{-1} of (4.11) or its super-lumped diagonal, see :meth:`HybridSolver.solve`.
from ..options import PROJECTIONS  # noqa: E402


class HybridSolver:
    """Hybrid method (Section 4.2): PCR on (4.5)/(4.13) with the preconditioner (4.11).

    Parameters
    ----------
    sub : Substructures
        Layout of a multibody scene (bodies own separate copies of the nodes
        on their common boundary).
    gi : GlobalInterface
        Global multipliers between bodies of ``sub``.

    Attributes
    ----------
    n_gamma : int
        Dimension of W^_{Gamma,c} (dofs on the local and global interfaces of
        all bodies, one per body copy).
    floating : ndarray of int, shape (n_float,)
        Floating bodies (no Dirichlet node); R_c has one column per floating
        body, the constants on its interface dofs.
    n_factorizations : int
        Factorizations computed in the constructor (interior solves, both
        primal-constrained solvers and their coarse problems). Later calls of
        :meth:`solve` never factor again.
    setup_seconds : float

    Notes
    -----
    Four sets of W entries are used: Gamma = ``sub.interface | gi.mask`` (the
    body interface of W^_{Gamma,c}), GL = ``gi.mask`` (the global interface,
    Gamma_OL of each body), Gamma_0 = ``sub.interface & ~gi.mask`` (the local
    interface away from the global one) and the subdomain interiors
    ``~Gamma``. Values of a node are distributed to all its subdomain copies
    before a subdomain operator (``K_W``, Dirichlet or primal-constrained
    solve) is applied and the copies are summed afterwards.
    """

    def __init__(self, sub: Substructures, gi: GlobalInterface) -> None:
        t0 = time.perf_counter()
        self.sub = sub
        self.gi = gi
        self.factorization_cache: dict = {}
        gamma_mask = sub.interface | gi.mask
        self.gamma_space = InterfaceSpace(sub, gamma_mask)                  # u_Gamma
        self.global_space = InterfaceSpace(sub, gi.mask)                    # Gamma_OL (global interface)
        self.local_space = InterfaceSpace(sub, sub.interface & ~gi.mask)    # Gamma_0 (local interface)
        self.n_gamma = self.gamma_space.n

        # S^_c through subdomain Dirichlet solves (interior = ~Gamma); the same
        # interior factorizations serve A_II^(i,j)^{-1} in (4.9)-(4.10).
        self.schur = DirichletSchur(sub, gamma_mask, self.factorization_cache)
        self.floating = np.asarray(gi.floating_bodies(), dtype=np.int64)
        # M_BDDC: A~ of every body, vertices primal, floating bodies pinned (S~^dagger).
        self.body_solver = PrimalConstrainedSolver(sub, sub.vertex, self.factorization_cache, fixed_bodies=self.floating)
        # S~_Gamma0^{-1} of (4.10): global-interface nodes held at zero (no floating body).
        self.local_interface_solver = PrimalConstrainedSolver(sub, sub.vertex, self.factorization_cache, exclude=gi.mask)
        self.n_factorizations = (self.schur.II.n_new_factorizations + self.body_solver.n_factorizations
                                 + self.local_interface_solver.n_factorizations)
        self._reported = False
        # interface restrictions of the two primal-constrained solvers (explicit dense blocks where they
        # pay off) and their operators on u_Gamma and Gamma_0, built on first use
        self._bddc_space_solve = None
        self._local_space_solve = None

        self.delta_gamma = sub.delta[self.gamma_space.idx]
        # diagonal of the body stiffness on the global interface (sum of the subdomain copies)
        self._K_global_diag = self.global_space.gather(sub.K_W.diagonal())
        self.delta_local = sub.delta[self.local_space.idx]

        # body of every u_Gamma dof; R_c columns (constants on floating bodies)
        body_of_entry = sub.body_of_sub[sub.sub_of_W]
        body_of_gamma = np.zeros(self.gamma_space.n, dtype=np.int64)
        body_of_gamma[self.gamma_space.pos] = body_of_entry[self.gamma_space.idx]
        self.body_of_gamma = body_of_gamma
        column = np.full(sub.scene.n_bodies, -1)
        column[self.floating] = np.arange(self.floating.size)
        self._column_of_body = column
        #: (n_gamma,) column of R_c of every u_Gamma dof (its floating body), -1 on clamped bodies
        self.kernel_column = column[body_of_gamma]
        self._floating_sums = FloatingSums(self.kernel_column, self.floating.size)
        self._kernel_count = self._floating_sums.counts                     # R_c^T R_c (diagonal)

        # global multipliers in the u_Gamma and GL index spaces
        pair_dofs = sub.dof_of_node[gi.pair_nodes]           # (n_gl, 2)
        self._pair_gamma = np.searchsorted(self.gamma_space.dofs, pair_dofs)
        self._pair_global = np.searchsorted(self.global_space.dofs, pair_dofs)
        self._pair_weight = gi.weight[gi.pairs]               # (n_gl, 2) weights of a and b
        self._pair_body = body_of_entry[gi.pairs]             # (n_gl, 2)
        if not (np.array_equal(self.gamma_space.dofs[self._pair_gamma], pair_dofs)
                and np.array_equal(self.global_space.dofs[self._pair_global], pair_dofs)):
            raise ValueError("global multipliers act on dofs outside the global interface")

        # condensed load g^_c = R^T (f_Gamma - A_GI A_II^{-1} f_I)
        self.g_hat = self.gamma_space.gather(self.schur.harmonic_extension_rhs(sub.f_W))
        self._active_cache: dict[bytes, ActiveSet] = {}
        self.build_operators()
        self.setup_seconds = time.perf_counter() - t0
        log.info("hybrid setup: n_gamma=%d, n_gl=%d, %d floating bodies, %d factorizations, %.3g s",
                 self.n_gamma, gi.n_gl, self.floating.size, self.n_factorizations, self.setup_seconds)

    # ----------------------------------------------------------- operators
    def build_operators(self) -> None:
        """Form now what the operators would otherwise form at their first application.

        That is the choice between explicit and implicit local Schur complements (with the
        dense blocks where explicit is chosen) and the interface restrictions of the two
        primal-constrained solvers, of M_BDDC^{-1} and of M_0 in (4.10) (their dense blocks
        where they pay off). Called by the constructor, so that this work is timed as setup,
        like the factorizations it continues, and the solve phase only iterates. The operators
        are the same as if formed at first use (the same decisions, the same numbers).
        """
        _ = self.schur.explicit
        self._bddc_operator()
        self._local_operator()

    def _bddc_operator(self):
        if self._bddc_space_solve is None:
            self._bddc_space_solve = (self.body_solver.interface(self.schur.gamma)
                                      .space_operator(self.gamma_space, self.delta_gamma))
        return self._bddc_space_solve

    def _local_operator(self):
        if self._local_space_solve is None:
            self._local_space_solve = (self.local_interface_solver.interface(self.schur.gamma)
                                       .space_operator(self.local_space, self.delta_local))
        return self._local_space_solve

    def S_hat(self, u: np.ndarray) -> np.ndarray:
        """S^_c u, the per-body assembled Schur complement, shape (n_gamma,) -> (n_gamma,)."""
        return self.schur.space_matvec(u, self.gamma_space, self.gamma_space)

    def M_bddc(self, r: np.ndarray) -> np.ndarray:
        """M_BDDC^{-1} r = R_D^T S~^dagger R_D r on every body, shape (n_gamma,) -> (n_gamma,).

        R_D scales the subdomain copies by delta-dagger (within the body); the
        primal copies are summed inside :class:`PrimalConstrainedSolver`.
        """
        return self._bddc_operator().apply(r)

    def P_R(self, u: np.ndarray) -> np.ndarray:
        """P_R = I - R_c (R_c^T R_c)^{-1} R_c^T: remove the mean on every floating body."""
        if self.floating.size == 0:
            return u
        return self._floating_sums.subtract(u, self._floating_sums.sums(u) / self._kernel_count)

    def kernel_load(self) -> np.ndarray:
        """e = R_c^T g^_c, shape (n_float,): G^kT lambda_0 = e fixes the multipliers' kernel part."""
        return self._floating_sums.sums(self.g_hat)

    def inexact_interior_solve(self, t: np.ndarray) -> np.ndarray:
        """A~_II^{-1} of (4.9)-(4.10) on every body, global-interface nodes held at zero.

        Parameters
        ----------
        t : ndarray, shape (n_W,)
            Unassembled right-hand side: subdomain interior entries are read
            as b_I^(j); the Gamma_0 copies are summed to the assembled b_Gamma0.

        Returns
        -------
        ndarray, shape (n_W,)
            x~ on the subdomain interiors and on every Gamma_0 copy (continuous),
            zero on the global interface.
        """
        y = self.schur.II.solve(t)                              # A_II^(j)^{-1} b_I^(j)
        s = t - self.sub.K_W @ y                                # b_Gamma0 - A_Gamma0I A_II^{-1} b_I (per copy)
        r0 = self.local_space.gather(s)                         # condensed residual of (4.10), assembled
        x0 = self.local_space.gather(self.local_interface_solver.solve(self.local_space.scatter(r0, self.delta_local)),
                                     self.delta_local)
        xw = self.local_space.scatter(x0)                       # x~_Gamma0 on all copies
        return y - self.schur.II.solve(self.sub.K_W @ xw) + xw  # (4.9)

    def S_ol(self, v: np.ndarray) -> np.ndarray:
        """Inexact body Schur complement S~_OL v = A_GG v - A_GI A~_II^{-1} A_IG v.

        Parameters
        ----------
        v : ndarray, shape (n_GL,)
            Values on the global-interface dofs (one per body copy).

        Returns
        -------
        ndarray, shape (n_GL,)
        """
        # Eliminating the subdomain interiors exactly (local Schur complements S = diag S^(i) on
        # Gamma) turns this into S~_OL v = (S (w - x~_Gamma0))_GL with w = v on the global
        # interface and x~_Gamma0 = M_0^{-1} (S w)_Gamma0, M_0^{-1} the primal-constrained solve of
        # (4.10) on the interface: the same operator as A_GG - A_GI A~_II^{-1} A_IG with A~_II^{-1}
        # of (4.9) (:meth:`inexact_interior_solve`), without interior solves when S is explicit.
        r0 = self.schur.space_matvec(v, self.global_space, self.local_space)
        x0 = self._local_solve(r0)
        return self.schur.space_matvec((v, -x0), (self.global_space, self.local_space), self.global_space)

    def _local_solve(self, r: np.ndarray) -> np.ndarray:
        """M_0 r: the primal-constrained solve of (4.10) on Gamma_0, shape (n_0,) -> (n_0,)."""
        return self._local_operator().apply(r)

    def S_ol_energy(self, v: np.ndarray) -> np.ndarray:
        """Energy form S~_E v = E^T S E v of the inexact body Schur complement, E v = [v; -M_0 S_0G v].

        The thesis's S~_OL = S_GG - S_G0 M_0 S_0G of (4.9)-(4.10) (:meth:`S_ol`)
        is indefinite when the BDDC-type M_0 exceeds S_00^{-1} in some direction
        (measured: eigenvalues down to -0.116 of P M_D^{-1} P at 58,913 dofs,
        docs/methods.md). With w = M_0 S_0G v,

            S~_E v = (S_GG v - S_G0 w) - S_G0 M_0 (S_0G v - S_00 w),

        the energy of the extension [v; -w] of v: positive semidefinite by
        construction, and equal to S~_OL (and to the exact body Schur complement)
        for M_0 = S_00^{-1}. Cost: one more M_0 and one more Schur product.

        Parameters
        ----------
        v : ndarray, shape (n_GL,)

        Returns
        -------
        ndarray, shape (n_GL,)
        """
        spaces = (self.global_space, self.local_space)
        w = self._local_solve(self.schur.space_matvec(v, self.global_space, self.local_space))
        z_global = self.schur.space_matvec((v, -w), spaces, self.global_space)
        z_local = self.schur.space_matvec((v, -w), spaces, self.local_space)
        return z_global - self.schur.space_matvec(self._local_solve(z_local), self.local_space, self.global_space)

    def inexact_schur(self, s_ol: str = "thesis"):
        """The operator S~_OL of M_D^{-1} in (4.11): :meth:`S_ol` (``"thesis"``) or :meth:`S_ol_energy`."""
        if s_ol not in S_OL_FORMS:
            raise InputError("s_ol", f"unknown form {s_ol!r} (choose from {', '.join(S_OL_FORMS)})")
        return self.S_ol if s_ol == "thesis" else self.S_ol_energy

    # ------------------------------------------------------------ active set
    def active_set(self, active: np.ndarray) -> ActiveSet:
        """Jump operators, G^k and the projection P^k for the mask Z^k (cached by the mask bytes).

        Raises
        ------
        ValueError
            If ``active`` has the wrong shape, or G^kT G^k is singular (a
            floating body, or a group of them, is not tied to a clamped body
            by active multipliers).
        """
        active = self.gi.active_mask(active)
        key = np.packbits(active).tobytes()
        hit = self._active_cache.get(key)
        if hit is not None:
            return hit
        first_gamma, second_gamma = self._pair_gamma[active, 0], self._pair_gamma[active, 1]
        weight_first, weight_second = self._pair_weight[active, 0], self._pair_weight[active, 1]
        n_act = first_gamma.size
        n_float = self.floating.size
        column_first = self._column_of_body[self._pair_body[active, 0]]
        column_second = self._column_of_body[self._pair_body[active, 1]]
        rows = np.r_[np.flatnonzero(column_first >= 0), np.flatnonzero(column_second >= 0)]
        cols = np.r_[column_first[column_first >= 0], column_second[column_second >= 0]]
        vals = np.r_[np.ones(int((column_first >= 0).sum())), -np.ones(int((column_second >= 0).sum()))]
        G = sp.csr_matrix((vals, (rows, cols)), shape=(n_act, n_float))
        projection = Projection(G, singular_tol=UNTIED_TOL, singular_message=UNTIED_MESSAGE)
        n_gamma, n_global = self.gamma_space.n, self.global_space.n
        aset = ActiveSet(
            active=active.copy(),
            jump=PairJump(first_gamma, second_gamma, n_gamma),
            # B_D: the entry of copy a is multiplied by the weight of b and vice versa
            scaled_jump_gamma=PairJump(first_gamma, second_gamma, n_gamma, weight_second, weight_first),
            scaled_jump_global=PairJump(self._pair_global[active, 0], self._pair_global[active, 1], n_global,
                                        weight_second, weight_first),
            G=G, projection=projection)
        if len(self._active_cache) > 16:
            self._active_cache.clear()
        self._active_cache[key] = aset
        return aset

    def projection(self, a: ActiveSet, kind: str = "orthogonal", s_ol: str = "thesis") -> Projection:
        """The projection onto V^k = ker(G^kT) of the given kind (cached on ``a``).

        ``"orthogonal"`` (or no floating bodies): P^k = ``a.projection`` of Section 4.2.
        ``"dirichlet"``: Q = M_D^{-1} of (4.11) (one application per floating body);
        ``"lumped"``: Q = Z B_{Gamma_OL,D} diag(K_GG) B_{Gamma_OL,D}^T Z, the
        super-lumped variant (diagonal of the stiffness on the global
        interface instead of S~_OL; no solves). See :class:`~ddsolve.dd.projection.Projection`.

        Raises
        ------
        ValueError
            For an unknown kind, or if G^kT Q G^k is singular. An indefinite one
            (Q = M_D^{-1} not positive definite) is factored by LU, with a warning.
        """
        if kind not in PROJECTIONS:
            raise InputError("projection", f"unknown projection {kind!r} (choose from {', '.join(PROJECTIONS)})")
        if kind == "orthogonal" or a.projection.k == 0:
            return a.projection
        key = kind if kind == "lumped" or s_ol == "thesis" else (kind, s_ol)   # Q = M_D^{-1} of that S~_OL
        hit = a.weighted.get(key)
        if hit is not None:
            return hit
        Q = (lambda g: self.M_D(a, g, s_ol)) if kind == "dirichlet" else (lambda g: self.M_lumped(a, g))
        # M_D^{-1} indefinite (e.g. multiplicity scaling across a checkerboard): P is still a
        # projection onto V^k, but PCR will meet the indefinite preconditioner (warning).
        out = Projection(a.G, Q, singular_tol=1e-12,
                         singular_message=f"G^T Q G of the {kind!r} projection is singular")
        a.weighted[key] = out
        return out

    def jump(self, a: ActiveSet, u: np.ndarray) -> np.ndarray:
        """Z B^_{Gamma,c} u, shape (n_gamma,) -> (n_act,)."""
        return a.jump.matvec(u)

    def jump_transpose(self, a: ActiveSet, lam: np.ndarray) -> np.ndarray:
        """(Z B^_{Gamma,c})^T lam, shape (n_act,) -> (n_gamma,)."""
        return a.jump.rmatvec(lam)

    def M_lumped(self, a: ActiveSet, lam: np.ndarray) -> np.ndarray:
        """Z B_{Gamma_OL,D} diag(K_GG) B_{Gamma_OL,D}^T Z lam: M_D^{-1} with S~_OL super-lumped."""
        return scaled_jump(a.scaled_jump_global, lambda v: self._K_global_diag * v)(lam)

    def M_D(self, a: ActiveSet, lam: np.ndarray, s_ol: str = "thesis") -> np.ndarray:
        """M_D^{-1} lam = Z B_{Gamma_OL,D} S~_OL B_{Gamma_OL,D}^T Z lam, shape (n_act,) -> (n_act,).

        B_{Gamma_OL,D}: body-level scaled jump, the entry of copy a multiplied
        by the weight of b's body and vice versa (``gi.weight``). ``s_ol``: the
        form of S~_OL (:meth:`inexact_schur`).
        """
        return scaled_jump(a.scaled_jump_global, self.inexact_schur(s_ol))(lam)

    # ---------------------------------------------------------------- solve
    def solve(self, active: np.ndarray, *, rtol: float = 1e-6, maxiter: int = 1000,
              x0: Any = None, restart: int = 100, norm: str = "l2",
              projection: str = "orthogonal", rtol_rule: str = "max",
              multiplier_weight: float = 1.0, s_ol: str = "thesis", check: bool | None = None,
              interior: bool = True) -> MethodOutput:
        """Solve the KKT system (4.2) on the active set Z^k: PCR on (4.5) with (4.11).

        The iteration runs on range(P_R) x V^k for (u_Gamma, mu) with
        lambda = lambda_0 + mu; afterwards u_Gamma is corrected by an element
        of ker(S^_c) so that Z B^_{Gamma,c} u_Gamma = 0, and the interior values
        follow by discrete harmonic extension.

        Parameters
        ----------
        active : ndarray of bool, shape (n_gl,)
            Active global multipliers (the diagonal of Z^k).
        rtol : float
            Stopping rule ||r_n|| <= rtol max(||r_0||, ||F_k||), F_k the
            right-hand side of (4.5): ||r_n|| / ||r_0|| < rtol for a zero initial
            guess (the rule of Section 4.4); a good warm start stops at the
            level a cold start would reach (``rtol_rule="max"``).
        maxiter : int
        x0 : dict or ndarray, optional
            Warm start: the ``extra["state"]`` of a previous solve (possibly on a
            different active set: multipliers are kept on pairs still active,
            zero elsewhere), or a flat vector (u_Gamma, mu) of length
            n_gamma + n_active in the unknowns of (4.5). It is projected onto
            range(P_R) x V^k before PCR starts.
        restart : int
            PCR cycles end after ``restart`` iterations; an unconverged cycle,
            or one whose recomputed residual is far above the recursive one, is
            restarted from its iterate (see :meth:`_pcr`).
        norm : {"l2", "M"}
            Norm of the stopping rule, of ``krylov.residuals`` and of
            ``krylov.true_residual``. ``"l2"`` (default, the thesis's rule of
            Section 4.4): ||r||_2, which adds the displacement-block residual
            (forces, ~ rho) to the multiplier-block residual (displacements,
            ~ 1/rho) and so depends on the coefficients' scale. ``"M"``:
            ||r||_B = <r, B^{-1} r>^{1/2} with B^{-1} the preconditioner (4.11),
            the norm PCR minimises (Lemma 1.3.2), invariant under such scalings.
        projection : {"orthogonal", "dirichlet", "lumped"}
            Projection onto V^k = ker(G^kT) in (4.5), (4.11) and (4.13).
            ``"orthogonal"`` (default): P^k = I - G (G^T G)^{-1} G^T of Section
            4.2. The others use FETI's Q-weighted projection
            P = I - Q G (G^T Q G)^{-1} G^T: the multiplier unknowns stay in
            range(P) = V^k, the multiplier equations become P^T Z B^ u_Gamma = 0
            (P^T vanishes on range(G^k) = Z B^ ker(S^_c), as P^k does) and the
            preconditioner block P M_D^{-1} P^T; the system stays symmetric and
            has the same solution. P^T is the Q-orthogonal projection, so it
            does not amplify the Q-norm of a residual; with Q = M_D^{-1}
            (``"dirichlet"``, rho-scaled) this keeps the multiplier block
            robust for coefficient jumps between subdomains of floating bodies
            (Klawonn & Widlund, CPAM 54 (2001), [35] of the thesis, for one-level
            FETI), which P^k is not. ``"lumped"``: Q = B_D diag(K_GG) B_D^T, a cheaper
            diagonal. Cost: one M_D^{-1} application per floating body and
            active set (``"dirichlet"``), cached.
        rtol_rule : {"max", "initial"}
            ``"max"`` (default): stop at ||r_n|| <= rtol max(||r_0||, ||F_k||).
            ``"initial"``: at ||r_n|| <= rtol ||r_0|| (Section 4.4 as printed, also
            for a warm start: the thesis preset, :mod:`ddsolve.presets`). The two
            agree for a zero initial guess (r_0 = F_k).
        multiplier_weight : float
            Weight c > 0 of the multiplier block in the stopping norm:
            ``norm="l2"`` measures (||r_u||^2 + c^2 ||r_lambda||^2)^{1/2}. PCR runs
            on D A D y = D b with D = diag(I, c I), x = D y, and the preconditioner
            D^{-1} M D^{-1}: the same iterates in exact arithmetic, only the
            stopping rule (and ``krylov``'s residuals) change. c = 1 (default) is
            the thesis's ||.||_2; c ~ ||S^_c|| (e.g. the coefficient scale
            max rho) balances forces r_u with displacements r_lambda and makes the
            rule invariant under rho -> s rho (the active set method's default).
        s_ol : {"thesis", "energy"}
            Form of S~_OL in M_D^{-1} of (4.11) (:data:`S_OL_FORMS`): ``"thesis"``
            (default) S_GG - S_G0 M_0 S_0G of (4.9)-(4.10) (:meth:`S_ol`), which can be
            indefinite, so that PCR may break down; ``"energy"`` the positive
            semidefinite E^T S E (:meth:`S_ol_energy`, one more M_0 per application).
        check : bool, optional
            The final error check (:func:`ddsolve.multibody.check.checked_output`): None (default) where
            rho varies between subdomains or the mesh is unstructured, True always, False never (the
            active set method's face solves, judged by the KKT conditions instead).
        interior : bool
            Compute ``u`` (default). False: ``u`` is None unless the check runs; :meth:`extend` gives it from
            ``extra["u_gamma"]`` (the active set method extends its last face solve only).

        Returns
        -------
        MethodOutput
            ``u`` shape (ndof,) (interior values by discrete harmonic extension),
            ``krylov`` the PCR result on (4.5), ``nlambda`` = active.sum(),
            ``n_factorizations`` new factorizations (0 after the first solve),
            ``extra = {"lambda": (n_active,), "state": dict, "u_gamma": (n_gamma,),
            "n_gamma": int, "n_floating": int, "constraint_residual": float, "s_ol": str}``, and
            ``"error_estimate"`` where the check ran (above its limit the result is not converged).

        Raises
        ------
        InputError (a ValueError)
            An unknown option, a wrong ``active`` or warm start shape; ValueError: a floating body not tied.
        """
        if norm not in NORMS:
            raise InputError("norm", f"unknown norm {norm!r} (choose from {', '.join(NORMS)})")
        if projection not in PROJECTIONS:
            raise InputError("projection", f"unknown projection {projection!r} (choose from {', '.join(PROJECTIONS)})")
        if rtol_rule not in RTOL_RULES:
            raise InputError("rtol_rule", f"unknown rule {rtol_rule!r} (choose from {', '.join(RTOL_RULES)})")
        if s_ol not in S_OL_FORMS:
            raise InputError("s_ol", f"unknown form {s_ol!r} (choose from {', '.join(S_OL_FORMS)})")
        rtol = check_tolerance("rtol", rtol)
        if isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer)) or maxiter < 1:
            raise InputError("maxiter", f"must be an integer >= 1, got {maxiter!r}")
        if check is not None:
            check = check_flag("check", check)
        if isinstance(restart, bool) or not isinstance(restart, (int, np.integer)) or restart < 1:
            raise InputError("restart", f"must be an integer >= 1, got {restart!r}")
        t0 = time.perf_counter()
        a = self.active_set(active)
        n_act = a.n_active
        n_g = self.gamma_space.n
        nf = self.floating.size

        # lambda_0 with G^T lambda_0 = e = R_c^T g^_c
        lam0 = a.projection.particular(self.kernel_load()) if nf else np.zeros(n_act)

        proj = self.projection(a, projection, s_ol)         # P^k of Section 4.2, or Q-weighted

        def A_op(x: np.ndarray) -> np.ndarray:                  # (4.13), P^k -> P, P^T
            u, mu = x[:n_g], x[n_g:]
            return np.concatenate([self.S_hat(u) + a.jump.rmatvec(proj.apply(mu)),
                                   proj.apply_transpose(a.jump.matvec(u))])

        def M_op(r: np.ndarray) -> np.ndarray:                  # (4.11), P^k M_D^{-1} P^k -> P M_D^{-1} P^T
            ru, rl = r[:n_g], r[n_g:]
            zu = self.P_R(self.M_bddc(self.P_R(ru)))
            zl = proj.apply(self.M_D(a, proj.apply_transpose(rl), s_ol))
            return np.concatenate([zu, zl])

        b = np.concatenate([self.g_hat - a.jump.rmatvec(lam0), np.zeros(n_act)])
        xs = self._initial_guess(a, x0, lam0, proj)
        n = n_g + n_act
        setup = time.perf_counter() - t0
        c = float(multiplier_weight)
        if not (c > 0.0 and math.isfinite(c)):
            raise InputError("multiplier_weight", f"must be positive and finite, got {multiplier_weight!r}")
        if c != 1.0:                                            # D A D y = D b, x = D y, D = diag(I, c I)
            A_c, M_c = A_op, M_op
            d = np.r_[np.ones(n_g), np.full(n_act, c)]

            def A_op(x: np.ndarray) -> np.ndarray:
                return d * A_c(d * x)

            def M_op(r: np.ndarray) -> np.ndarray:
                return M_c(r / d) / d

            b = d * b
            xs = None if xs is None else xs / d
        kr = (self._pcr(linear_operator(n, A_op), b, xs, linear_operator(n, M_op), rtol, maxiter, restart,
                        norm=norm, relative_to_rhs=rtol_rule == "max") if n else
              KrylovResult.solved_directly(0, "interface unknowns"))      # one part per body, no multipliers
        u_g = kr.x[:n_g]
        mu = kr.x[n_g:] * c if c != 1.0 else kr.x[n_g:]
        lam = lam0 + proj.apply(mu)
        # u_Gamma - R_c (G^T G)^{-1} G^T Z B^ u_Gamma (after (4.5))
        if nf:
            beta = a.projection.coefficients(a.jump.matvec(u_g))
            u_g = u_g - np.where(self.kernel_column >= 0, beta[np.maximum(self.kernel_column, 0)], 0.0)
        u = self.extend(u_g) if interior or check is not False else None
        jump = float(np.abs(a.jump.matvec(u_g)).max()) if n_act else 0.0
        lam_full = np.zeros(self.gi.n_gl)
        lam_full[a.active] = lam
        new_fact = 0 if self._reported else self.n_factorizations
        self._reported = True
        log.info("hybrid solve: %d active multipliers, %s", n_act, kr.reason)
        out = MethodOutput(
            u=u, krylov=kr, nlambda=int(n_act), n_factorizations=new_fact,
            setup_seconds=setup + (self.setup_seconds if new_fact else 0.0),
            extra={"lambda": lam, "u_gamma": u_g, "n_gamma": n_g, "n_floating": int(nf),
                   "constraint_residual": jump, "s_ol": s_ol,
                   "state": {"u_gamma": u_g.copy(), "lambda": lam_full, "active": a.active.copy()}})
        return checked_output(out, self.gi, active, rtol, "hybrid", check)

    def extend(self, u_gamma: np.ndarray) -> np.ndarray:
        """u (ndof,) from u_Gamma (n_gamma,): A_II^{-1} (f_I - A_IG u_Gamma) per subdomain, averaged (as :meth:`solve`)."""
        return self.sub.average(self.schur.interior_solution(self.sub.f_W, self.gamma_space.scatter(u_gamma)))

    def system(self, active: np.ndarray, *, x0: Any = None, projection: str = "orthogonal",
               s_ol: str = "thesis") -> tuple[Any, Any, np.ndarray, np.ndarray | None]:
        """The system PCR solves in :meth:`solve`: ``(A, M, b, x0)`` of (4.13)/(4.5) with (4.11).

        For analysis (e.g. :func:`ddsolve.krylov.optimal.minimal_residual_counts`
        or a tiny exact spectrum of ``M A``); :meth:`solve` builds the same
        operators.

        Parameters
        ----------
        active : ndarray of bool, shape (n_gl,)
        x0 : dict or ndarray, optional
            Warm start as in :meth:`solve`.
        projection : {"orthogonal", "dirichlet", "lumped"}
        s_ol : {"thesis", "energy"}
            Form of S~_OL in (4.11), as in :meth:`solve`.

        Returns
        -------
        A : LinearOperator, shape (n, n)
            The symmetric indefinite operator of (4.13), n = n_gamma + n_active.
        M : LinearOperator, shape (n, n)
            The SPD (on range(P_R) x V^k) preconditioner (4.11).
        b : ndarray, shape (n,)
            The right-hand side of (4.5) (lambda_0 eliminated).
        x0 : ndarray, shape (n,), or None
            The projected initial guess (None: zero).
        """
        if projection not in PROJECTIONS:
            raise InputError("projection", f"unknown projection {projection!r} (choose from {', '.join(PROJECTIONS)})")
        a = self.active_set(active)
        n_g, n_act = self.gamma_space.n, a.n_active
        lam0 = a.projection.particular(self.kernel_load()) if self.floating.size else np.zeros(n_act)
        proj = self.projection(a, projection, s_ol)

        def A_op(x: np.ndarray) -> np.ndarray:
            u, mu = x[:n_g], x[n_g:]
            return np.concatenate([self.S_hat(u) + a.jump.rmatvec(proj.apply(mu)),
                                   proj.apply_transpose(a.jump.matvec(u))])

        def M_op(r: np.ndarray) -> np.ndarray:
            zu = self.P_R(self.M_bddc(self.P_R(r[:n_g])))
            zl = proj.apply(self.M_D(a, proj.apply_transpose(r[n_g:]), s_ol))
            return np.concatenate([zu, zl])

        b = np.concatenate([self.g_hat - a.jump.rmatvec(lam0), np.zeros(n_act)])
        n = n_g + n_act
        return (linear_operator(n, A_op), linear_operator(n, M_op), b,
                self._initial_guess(a, x0, lam0, proj))

    @staticmethod
    def _pcr(A: Any, b: np.ndarray, x0: np.ndarray | None, M: Any, rtol: float, maxiter: int,
             restart: int, norm: str = "l2", relative_to_rhs: bool = True) -> KrylovResult:
        """PCR on (4.14) with restarts; stop at ||r_n|| <= rtol max(||r_0||, ||F_k||).

        ``relative_to_rhs=False``: at ||r_n|| <= rtol ||r_0|| (``rtol_rule="initial"``).

        All norms (the threshold, the recursive and the recomputed residuals)
        are ``norm``: ||.||_2, or ||r||_B = <r, B^{-1} r>^{1/2} with B^{-1} = ``M``
        the preconditioner (4.11).

        The two-term recurrence of :func:`ddsolve.krylov.pcr` can lose the
        accuracy of its recursive residual after a near-zero pivot <z, A z>
        (indefinite A), e.g. for a warm start whose displacement block of the
        residual is tiny; the recursive residual then stagnates far from the
        true one. Each cycle is therefore limited to ``restart`` iterations and
        restarted from its iterate, with the true residual, when it did not
        reach the threshold (by the recomputed residual): the restart policy of
        :meth:`ddsolve.krylov.KrylovSolver.restarted` with ``atol = rtol ||F_k||``
        (a cycle is accepted within
        :data:`~ddsolve.krylov.convergence.RESTART_FACTOR` of the threshold).

        Returns
        -------
        KrylovResult
            Iterations, matvecs, seconds and residual histories of all cycles;
            ``restarts`` the number of restarts.
        """
        atol = rtol * PCR.rhs_norm(b, M, norm) if relative_to_rhs else 0.0
        if not math.isfinite(atol):      # b beyond the double range (rho 1e-20, f 1e300): PCR reports the
            atol = 0.0                   # non-finite residual as a breakdown; an inf atol was an input error
        return PCR.restarted(A, b, x0, rtol=rtol, atol=atol, maxiter=maxiter, restart=restart,
                             M=M, norm=norm)

    def _initial_guess(self, a: ActiveSet, x0: Any, lam0: np.ndarray,
                       proj: Projection | None = None) -> np.ndarray | None:
        """Map a warm start to range(P_R) x V^k: u0 = P_R u_Gamma, mu0 = P (lambda - lambda_0).

        P is ``proj`` (P^k, or a Q-weighted projection, see :meth:`projection`); None: P^k.
        """
        if x0 is None:
            return None
        proj = a.projection if proj is None else proj
        n_g = self.gamma_space.n
        if isinstance(x0, dict):
            u0 = np.asarray(x0["u_gamma"], dtype=float)
            lam_full = np.asarray(x0["lambda"], dtype=float)
            if lam_full.shape == (self.gi.n_gl,):
                lam = lam_full[a.active]
            elif "active" in x0 and lam_full.shape == (int(np.sum(x0["active"])),):
                full = np.zeros(self.gi.n_gl)
                full[np.asarray(x0["active"], dtype=bool)] = lam_full
                lam = full[a.active]
            else:
                raise InputError("x0", "the warm start's lambda has the wrong shape")
        else:
            x = np.asarray(x0, dtype=float)
            if x.shape != (n_g + a.n_active,):
                raise InputError("x0", f"must have shape ({n_g + a.n_active},), got {x.shape}")
            u0, lam = x[:n_g], x[n_g:] + lam0
        if u0.shape != (n_g,):
            raise InputError("x0", f"the warm start's u_gamma must have shape ({n_g},), got {u0.shape}")
        return np.concatenate([self.P_R(u0), proj.apply(lam - lam0)])
