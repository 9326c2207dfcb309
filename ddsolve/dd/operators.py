"""Subdomain-based operators shared by the FETI, FETI-DP and BDDC solvers.

All operators act on W vectors (see :mod:`ddsolve.dd.substructure`) and are
applied through batched subdomain solves; none forms a global dense matrix.
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .local import BatchedSolver
from .substructure import Substructures

log = logging.getLogger(__name__)


class DirichletSchur:
    """Local Schur complements S = diag(S^(i)) applied on the interface (Section 2.4).

    S^(i) = A_GG^(i) - A_GI^(i) A_II^(i)^{-1} A_IG^(i), applied as
    S w = (K w - K A_II^{-1} (K w)_I)_Gamma for w supported on the interface
    entries, with one batched interior (Dirichlet) solve.

    Parameters
    ----------
    sub : Substructures
    gamma_mask : ndarray of bool, shape (n_W,)
        The local interface Gamma_i; everything else free is interior.
    cache : dict
        Shared factorization cache.
    exclude : ndarray of bool, shape (n_W,), optional
        Entries treated as Dirichlet nodes (removed from the interior).
    """

    def __init__(self, sub: Substructures, gamma_mask: np.ndarray, cache: dict,
                 exclude: np.ndarray | None = None) -> None:
        self.sub = sub
        self.gamma = gamma_mask
        self.interior = ~gamma_mask if exclude is None else ~gamma_mask & ~exclude
        self.II = BatchedSolver(sub, self.interior, cache)

    def matvec(self, w: np.ndarray) -> np.ndarray:
        """S w for a W vector (read on Gamma); result is zero off Gamma."""
        w = np.where(self.gamma, w, 0.0)
        t = self.sub.K_W @ w
        z = self.II.solve(t)
        y = t - self.sub.K_W @ z
        return np.where(self.gamma, y, 0.0)

    def harmonic_extension_rhs(self, f: np.ndarray) -> np.ndarray:
        """g = f_Gamma - A_GI A_II^{-1} f_I (condensed load), zero off Gamma."""
        z = self.II.solve(f)
        return np.where(self.gamma, f - self.sub.K_W @ z, 0.0)

    def interior_solution(self, f: np.ndarray, w_gamma: np.ndarray) -> np.ndarray:
        """Complete interface values by u_I = A_II^{-1} (f_I - A_IG w_Gamma); returns a full W vector."""
        w = np.where(self.gamma, w_gamma, 0.0)
        return w + self.II.solve(f - self.sub.K_W @ w)


class PrimalConstrainedSolver:
    """Solves with A~ of (2.17): subdomains coupled only at the primal vertices.

    The primal unknowns W_Pi (global vertex dofs) are eliminated through the
    coarse matrix
        S_PiPi = sum_i R_Pi^(i)T (A_PiPi^(i) - A_Pir^(i) A_rr^(i)^{-1} A_rPi^(i)) R_Pi^(i),
    with r = I + Delta. With Psi^(i) = A_rr^(i)^{-1} A_rPi^(i) (precomputed per
    shared factorization), one application of A~^{-1} costs one batched
    A_rr solve and one coarse solve:
        x_r0 = A_rr^{-1} b_r,   u_Pi = S_PiPi^{-1} (b_Pi - sum_i R_Pi^T Psi^T b_r),
        x_r  = x_r0 - Psi R_Pi u_Pi.

    Parameters
    ----------
    sub : Substructures
    primal_mask : ndarray of bool, shape (n_W,)
        Primal W entries (subdomain copies of the vertex dofs).
    cache : dict
        Shared factorization cache.
    exclude : ndarray of bool, shape (n_W,), optional
        Entries treated as Dirichlet nodes (zero in the solution).
    fixed_bodies : sequence of int, optional
        Floating bodies: one primal dof of each is pinned to zero, which turns
        the singular A~ of such a body into a generalized inverse A~^+
        (A~ A~^+ A~ = A~), as needed for S~^dagger in (4.11) and F in (3.35).
    """

    def __init__(self, sub: Substructures, primal_mask: np.ndarray, cache: dict,
                 exclude: np.ndarray | None = None, fixed_bodies=()) -> None:
        self.sub = sub
        if exclude is not None:
            primal_mask = primal_mask & ~exclude
        self.primal = primal_mask
        self.r = ~primal_mask if exclude is None else ~primal_mask & ~exclude
        self.rr = BatchedSolver(sub, self.r, cache)
        # global primal numbering
        prim_dofs = np.unique(sub.l2g[primal_mask])
        self.n_primal = prim_dofs.size
        coarse_of_W = np.full(sub.n_W, -1)
        coarse_of_W[primal_mask] = np.searchsorted(prim_dofs, sub.l2g[primal_mask])
        self.coarse_of_W = coarse_of_W
        # primal entries of each subdomain, padded: (n_sub, p_max)
        pw = np.flatnonzero(primal_mask)
        psub = sub.sub_of_W[pw]
        counts = np.bincount(psub, minlength=sub.n_sub)
        p_max = int(counts.max()) if pw.size else 0
        rank = np.arange(pw.size) - np.concatenate([[0], np.cumsum(counts)])[psub]
        table = np.full((sub.n_sub, max(p_max, 1)), -1)
        table[psub, rank] = pw
        self.table = table[:, :p_max]
        self.p_max = p_max
        valid = self.table >= 0
        # K_rPi columns and Psi = A_rr^{-1} A_rPi for all subdomains at once: (n_W, p_max)
        KrP = np.zeros((sub.n_W, p_max))
        KPP = np.zeros((sub.n_sub, p_max, p_max))
        for c in range(p_max):
            e = np.zeros(sub.n_W)
            e[self.table[valid[:, c], c]] = 1.0
            col = sub.K_W @ e
            KrP[:, c] = np.where(self.r, col, 0.0)
            for c2 in range(p_max):
                ok = valid[:, c2]
                KPP[ok, c2, c] = col[self.table[ok, c2]]
        self.Psi = self.rr.solve_columns(KrP) if p_max else KrP
        # Psi columns of entry e belong to its subdomain's primal c; coarse index per (W entry, c)
        self.coarse_cols = np.where(valid, coarse_of_W[np.maximum(self.table, 0)], -1)  # (n_sub, p_max)
        # local coarse matrices: KPP - KrP^T Psi, per subdomain
        seg = sub.offsets[:-1]
        S_loc = KPP.copy()
        for c in range(p_max):
            for c2 in range(p_max):
                prod = KrP[:, c] * self.Psi[:, c2]
                S_loc[:, c, c2] -= np.add.reduceat(prod, seg) if sub.n_W else 0.0
        rows = np.broadcast_to(self.coarse_cols[:, :, None], S_loc.shape)
        cols = np.broadcast_to(self.coarse_cols[:, None, :], S_loc.shape)
        ok = (rows >= 0) & (cols >= 0)
        S_PiPi = sp.csr_matrix((S_loc[ok], (rows[ok], cols[ok])), shape=(self.n_primal, self.n_primal))
        pinned = []
        for body in fixed_bodies:
            cand = np.flatnonzero(primal_mask & (sub.body_of_sub[sub.sub_of_W] == body))
            if cand.size == 0:
                raise ValueError(f"floating body {body} has no primal vertex to pin")
            pinned.append(coarse_of_W[cand[0]])
        self.pinned = np.asarray(pinned, dtype=np.int64)
        if self.pinned.size:
            keep = np.ones(self.n_primal)
            keep[self.pinned] = 0.0
            D = sp.diags(keep)
            S_PiPi = D @ S_PiPi @ D + sp.diags(1.0 - keep)
        self.S_PiPi = S_PiPi.tocsc()
        self.coarse = spla.splu(self.S_PiPi, permc_spec="MMD_AT_PLUS_A") if self.n_primal else None
        self.n_factorizations = self.rr.n_new_factorizations + (1 if self.n_primal else 0)
        self._entry_cols = self.coarse_cols[sub.sub_of_W] if p_max else np.zeros((sub.n_W, 0), dtype=int)
        # Psi as one sparse (n_W, n_primal) matrix: column c of entry e goes to its coarse dof
        ok = self._entry_cols >= 0
        rows = np.broadcast_to(np.arange(sub.n_W)[:, None], ok.shape)[ok]
        self._Psi_global = sp.csr_matrix((self.Psi[ok], (rows, self._entry_cols[ok])),
                                         shape=(sub.n_W, self.n_primal))
        self._Psi_global_T = self._Psi_global.T.tocsr()

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x = A~^{-1} b for a W vector b; primal copies of b are summed (assembled).

        Returns a W vector whose primal entries all hold the (continuous) primal value.
        """
        sub = self.sub
        br = np.where(self.r, b, 0.0)
        x = self.rr.solve(br)
        if self.n_primal == 0:
            return x
        b_pi = np.bincount(self.coarse_of_W[self.primal], weights=b[self.primal], minlength=self.n_primal)
        b_pi -= self._Psi_global_T @ br                 # assembled Psi^T b_r
        b_pi[self.pinned] = 0.0
        u_pi = self.coarse.solve(b_pi)
        x -= self._Psi_global @ u_pi
        x[self.primal] = u_pi[self.coarse_of_W[self.primal]]
        return x


def linear_operator(n: int, matvec) -> spla.LinearOperator:
    """Wrap a matvec as a symmetric scipy LinearOperator of shape (n, n)."""
    return spla.LinearOperator((n, n), matvec=matvec, rmatvec=matvec, dtype=float)
