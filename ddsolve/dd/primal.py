"""The primal-constrained solve A~^{-1} of (2.17) and its interface restrictions.

:class:`PrimalConstrainedSolver` (subdomains coupled only at the primal
unknowns, the coarse problem S_PiPi eliminated) is used by FETI-DP, BDDC,
FETI-FETI and the hybrid method. Its :meth:`~PrimalConstrainedSolver.interface`
hands out A~^{-1} restricted to an interface, either through the full batched
solve (:class:`ImplicitInterfaceSolve`) or through dense blocks
(A_rr^{-1})_{DD} formed once from the existing factorizations
(:class:`ExplicitInterfaceSolve`), with the same rule as the explicit local
Schur complements of :class:`ddsolve.dd.operators.DirichletSchur` (the
thresholds ``EXPLICIT_SETUP_MATVECS`` and ``EXPLICIT_MAX_BLOCK`` are read from
:mod:`ddsolve.dd.operators` at use, so patching them there applies to both).
Split from :mod:`ddsolve.dd.operators`, which re-exports every name.
"""
from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from . import operators as _operators
from .coarse import coarse_factor
from .local import (
    GROUPS_LOOP_MAX,
    BatchedSolver,
    DenseBlocks,
    _BlockView,
    _Group,
    solve_chunk,
    solve_many,
)
from .operators import space_key
from .substructure import Substructures

log = logging.getLogger(__name__)

#: Interface solves (one per mask) kept by a :class:`PrimalConstrainedSolver`, least recently used dropped.
MAX_INTERFACES = 4


def first_entry_of_bodies(mask: np.ndarray, body_of_entry: np.ndarray, bodies) -> np.ndarray:
    """The first entry with ``mask`` of each of ``bodies`` (the pinned primal vertex of a floating body),
    shape (len(bodies),), in one pass (a pass per body was O(n_bodies n); a review).

    ``mask`` (n,) bool, ``body_of_entry`` (n,) int. Raises ``ValueError`` naming the first body of
    ``bodies`` with no entry in ``mask``.
    """
    bodies = np.asarray(bodies, dtype=np.int64).reshape(-1)
    entries = np.flatnonzero(mask)
    owners, first = np.unique(body_of_entry[entries], return_index=True)
    at = np.minimum(np.searchsorted(owners, bodies), max(owners.size - 1, 0))
    found = owners[at] == bodies if owners.size else np.zeros(bodies.size, dtype=bool)
    if not found.all():
        raise ValueError(f"floating body {int(bodies[~found][0])} has no primal vertex to pin")
    return entries[first[at]]


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
        prim_dofs = self._primal_dofs(sub, primal_mask)
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
        # Psi = A_rr^{-1} A_rPi and the local coarse matrices A_PiPi - A_Pir Psi. A^(i) = rho_i K_t, so
        # Psi^(i) = K_t,rr^{-1} K_t,rPi is shared by all members of a factorization group with the same
        # primal local set: one solve with p columns per group, not per subdomain.
        self.Psi = np.zeros((sub.n_W, p_max))
        S_loc = np.zeros((sub.n_sub, p_max, p_max))
        done = np.zeros(sub.n_sub, dtype=bool)
        # the subdomains of the batched factorization: all at once, from K_W (no loop over subdomains)
        batch = self.rr._batch
        if batch is not None:
            done[self._batched_primal_blocks(sub, batch, S_loc)] = True
        # all solves K_rr^{-1} K_rPi first (shared factorizations: multi-column solves), then Psi, S
        work: list[tuple[_Group, list[int], np.ndarray, np.ndarray, np.ndarray | None]] = []
        for g in self.rr.groups:
            members = g.members
            if batch is not None and isinstance(g.factor, _BlockView) and g.factor.factor is batch[0]:
                continue
            by_primal: dict[bytes, list[int]] = {}
            for j, s_ in enumerate(members):
                loc_p = sub.local_index[self.table[s_][valid[s_]]]
                by_primal.setdefault(loc_p.astype(np.int64).tobytes(), []).append(j)
            for js in by_primal.values():
                s0 = members[js[0]]
                loc_p = sub.local_index[self.table[s0][valid[s0]]]
                K = sub.stiffness[int(sub.template[s0])]
                KpP = K[loc_p][:, loc_p].toarray()
                KrP_t = K[g.loc][:, loc_p].toarray() if loc_p.size else None
                work.append((g, js, loc_p, KpP, KrP_t))
        solved = iter(solve_many([(g.factor, KrP_t) for g, _, _, _, KrP_t in work if KrP_t is not None]))
        for g, js, loc_p, KpP, KrP_t in work:
            p = loc_p.size
            if p:
                Psi_t = next(solved)
                S_t = KpP - KrP_t.T @ Psi_t
                idx = g.index[:, js]                                    # (n_r, n_js)
                for c in range(p):
                    self.Psi[idx, c] = Psi_t[:, c][:, None]
            else:
                S_t = KpP
            sel = np.asarray(g.members)[js]
            S_loc[sel, :p, :p] = sub.rho[sel][:, None, None] * S_t[None]
            done[sel] = True
        for s_ in np.flatnonzero(~done & (valid.sum(axis=1) > 0)):      # no r entries: S = A_PiPi
            loc_p = sub.local_index[self.table[s_][valid[s_]]]
            p = loc_p.size
            S_loc[s_, :p, :p] = sub.rho[s_] * sub.stiffness[int(sub.template[s_])][loc_p][:, loc_p].toarray()
        # Psi columns of entry e belong to its subdomain's primal c; coarse index per (W entry, c)
        self.coarse_cols = np.where(valid, coarse_of_W[np.maximum(self.table, 0)], -1)  # (n_sub, p_max)
        rows = np.broadcast_to(self.coarse_cols[:, :, None], S_loc.shape)
        cols = np.broadcast_to(self.coarse_cols[:, None, :], S_loc.shape)
        ok = (rows >= 0) & (cols >= 0)
        S_PiPi = sp.csr_matrix((S_loc[ok], (rows[ok], cols[ok])), shape=(self.n_primal, self.n_primal))
        S_PiPi = self._assemble_coarse(S_PiPi)
        self.pinned = coarse_of_W[first_entry_of_bodies(primal_mask, sub.body_of_sub[sub.sub_of_W], fixed_bodies)]
        if self.pinned.size:
            keep = np.ones(self.n_primal)
            keep[self.pinned] = 0.0
            D = sp.diags(keep)
            S_PiPi = D @ S_PiPi @ D + sp.diags(1.0 - keep)
        self.S_PiPi = S_PiPi.tocsc()
        self.coarse = self._factor_coarse(self.S_PiPi) if self.n_primal else None
        self.n_factorizations = self.rr.n_new_factorizations + (1 if self.n_primal else 0)
        self._psi_global: sp.csr_matrix | None = None      # Psi as sparse (n_W, n_primal), on first use
        self._psi_global_T: sp.csr_matrix | None = None
        # by (mask bytes, n_W, explicit option), the MAX_INTERFACES most recently used
        self._interfaces: OrderedDict[tuple, InterfaceSolve] = OrderedDict()

    def _batched_primal_blocks(self, sub: Substructures, batch: tuple, S_loc: np.ndarray) -> np.ndarray:
        """Psi and the local coarse matrices of the subdomains of the batched factorization, all at once.

        With K_W = diag(rho_i K^(i)) and r, Pi the r and primal entries of those subdomains,
        column c of Psi^(i) = K_rr^(i)^{-1} K_rPi^(i) is column c of one solve with the
        block-diagonal factor of diag(K_rr^(i)) (right-hand side: column c of every
        subdomain's K_rPi^(i) on its rows, as :func:`~ddsolve.dd.local.solve_many` packs
        them), and S^(i) = rho_i (K_PiPi^(i) - K_Pir^(i) Psi^(i)) = (K_W)_PiPi - (K_W)_Pir Psi
        follows from two block-diagonal sparse products.

        Parameters
        ----------
        batch : tuple
            ``BatchedSolver._batch``: (factor, entries (n_b,), 1 / rho of each entry (n_b,)).
        S_loc : ndarray, shape (n_sub, p_max, p_max)
            Written for the batched subdomains.

        Returns
        -------
        ndarray of int
            The batched subdomains.
        """
        factor, entries, inv_rho = batch
        members = np.unique(sub.sub_of_W[entries])
        in_batch = np.zeros(sub.n_sub, dtype=bool)
        in_batch[members] = True
        column = np.full(sub.n_W, -1, dtype=np.int64)          # primal entry -> its column c in its subdomain
        s_idx, c_idx = np.nonzero(self.table >= 0)
        column[self.table[s_idx, c_idx]] = c_idx
        pw = np.flatnonzero(self.primal & in_batch[sub.sub_of_W])
        if pw.size == 0 or self.p_max == 0:
            return members
        # the (Pi, r) and (Pi, Pi) blocks from the primal rows of K_W (symmetric: K_rPi = K_Pir^T)
        position = np.full(sub.n_W, -1, dtype=np.int64)
        position[entries] = np.arange(entries.size)            # row of the batched factor
        primal_index = np.full(sub.n_W, -1, dtype=np.int64)
        primal_index[pw] = np.arange(pw.size)
        rows = sp.csr_matrix(sub.K_W)[pw].tocoo()               # (n_pb, n_W): few rows
        to_r, to_P = position[rows.col] >= 0, primal_index[rows.col] >= 0
        KrP = sp.coo_matrix((rows.data[to_r], (position[rows.col[to_r]], rows.row[to_r])),
                            shape=(entries.size, pw.size))       # (n_b, n_pb), block diagonal
        KPP = sp.coo_matrix((rows.data[to_P], (rows.row[to_P], primal_index[rows.col[to_P]])),
                            shape=(pw.size, pw.size))
        # column chunks as solve_many makes them; rows and coarse rows of the subdomains with a column there
        col = column[pw[KrP.col]]
        KPr = sp.csr_matrix((KrP.data, (KrP.col, KrP.row)), shape=(pw.size, entries.size))
        s_of = sub.sub_of_W[pw]
        S_loc[s_of[KPP.row], column[pw[KPP.row]], column[pw[KPP.col]]] = KPP.data
        n_primal_of = (self.table >= 0).sum(axis=1)
        chunk = solve_chunk(entries.size)
        for c0 in range(0, self.p_max, chunk):
            c1 = min(c0 + chunk, self.p_max)
            here = (col >= c0) & (col < c1)
            rhs = np.zeros((entries.size, c1 - c0), order="F")
            rhs[KrP.row[here], col[here] - c0] = KrP.data[here] * inv_rho[KrP.row[here]]   # rho_i K_t -> K_t
            Y = factor.solve(rhs)
            live = np.flatnonzero(n_primal_of[sub.sub_of_W[entries]] > c0)
            self.Psi[entries[live], c0:c1] = Y[live]
            S_loc[s_of, column[pw], c0:c1] -= KPr @ Y             # (K_W)_Pir Psi, row by primal entry
        return members

    def _primal_dofs(self, sub: Substructures, primal_mask: np.ndarray) -> np.ndarray:
        """Sorted global dofs of the primal unknowns (hook: a rank-local ``sub`` sees only its own)."""
        return np.unique(sub.l2g[primal_mask])

    def _assemble_coarse(self, S_PiPi: sp.csr_matrix) -> sp.csr_matrix:
        """The coarse matrix from the subdomains' contributions (hook: summed over ranks in parallel)."""
        return S_PiPi

    def _factor_coarse(self, S_PiPi: sp.csc_matrix):
        """The factor of the coarse matrix (hook: a rank factors only the blocks it reads)."""
        return coarse_factor(S_PiPi)

    @property
    def Psi_global(self) -> sp.csr_matrix:
        """Psi as one sparse (n_W, n_primal) matrix: column c of entry e goes to its coarse dof."""
        if self._psi_global is None:
            sub = self.sub
            entry_cols = self.coarse_cols[sub.sub_of_W] if self.p_max else np.zeros((sub.n_W, 0), dtype=int)
            ok = entry_cols >= 0
            # CSR written directly (rows in order; no (row, column) pair twice), columns sorted in each row:
            # the matrix of the COO construction, without its conversion of n_W x p_max triplets
            indptr = np.concatenate([[0], np.cumsum(ok.sum(axis=1))])
            P = sp.csr_matrix((self.Psi[ok], entry_cols[ok], indptr), shape=(sub.n_W, self.n_primal))
            P.sort_indices()
            self._psi_global, self._psi_global_T = P, P.T.tocsr()
        return self._psi_global

    @property
    def Psi_global_T(self) -> sp.csr_matrix:
        """Psi^T as sparse (n_primal, n_W)."""
        if self._psi_global_T is None:
            self._psi_global_T = self.Psi_global.T.tocsr()
        return self._psi_global_T

    def assemble_basis(self) -> None:
        """Build the sparse Psi and Psi^T that :meth:`solve` uses now, in the setup of a method that
        will solve, rather than in its first solve."""
        if self.n_primal:
            self.Psi_global_T

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x = A~^{-1} b for a W vector b; primal copies of b are summed (assembled).

        Returns a W vector whose primal entries all hold the (continuous) primal value.
        """
        br = np.where(self.r, b, 0.0)
        x = self.rr.solve(br)
        if self.n_primal == 0:
            return x
        b_pi = np.bincount(self.coarse_of_W[self.primal], weights=b[self.primal], minlength=self.n_primal)
        b_pi = b_pi.astype(float, copy=False)          # bincount of no entries is int64 (a rank with no primal dof)
        b_pi -= self.Psi_global_T @ br                 # assembled Psi^T b_r
        b_pi[self.pinned] = 0.0
        u_pi = self.coarse.solve(b_pi)
        x -= self.Psi_global @ u_pi
        x[self.primal] = u_pi[self.coarse_of_W[self.primal]]
        return x

    def _explicit_pays_off(self, mask: np.ndarray) -> tuple[bool, float | None]:
        """Whether the dense interface blocks of ``mask`` pay off (the rule of ``DirichletSchur``).

        Forming them costs one local solve per interface unknown of each distinct
        (template, r set, interface pattern); one implicit :meth:`solve` costs one per
        subdomain. Explicit when the former is at most ``EXPLICIT_SETUP_MATVECS`` of the
        latter and no block exceeds ``EXPLICIT_MAX_BLOCK``. With few, large subdomains
        (H/h = 128 or more) the implicit solve is cheaper over a solve.

        Returns
        -------
        explicit : bool
        switch_after : float or None
            When not explicit but the blocks fit: the setup cost in implicit applications,
            after which :class:`ImplicitInterfaceSolve` forms them after all (see there).
        """
        cols, biggest = 0, 0
        for g in self.rr.groups:
            pattern = np.ascontiguousarray(np.packbits(mask[g.index], axis=0).T)   # one row per member
            rows = pattern.view(np.dtype((np.void, pattern.shape[1]))).ravel()
            _, first = np.unique(rows, return_index=True)                           # distinct patterns
            n_d = np.count_nonzero(mask[g.index][:, first], axis=0)
            cols, biggest = cols + int(n_d.sum()), max(biggest, int(n_d.max(initial=0)))
        fits = biggest <= _operators.EXPLICIT_MAX_BLOCK
        explicit = cols <= _operators.EXPLICIT_SETUP_MATVECS * max(self.sub.n_sub, 1) and fits
        log.debug("PrimalConstrainedSolver: %s interface blocks (%d setup columns, largest %d)",
                  "explicit" if explicit else "implicit", cols, biggest)
        return explicit, (cols / max(self.sub.n_sub, 1) if fits and not explicit else None)

    def interface(self, mask: np.ndarray, explicit: bool | None = None) -> InterfaceSolve:
        """A~^{-1} restricted to the interface ``mask`` (explicit dense blocks or implicit solves).

        ``mask`` (an interface: every interior entry of the subdomains is outside it).
        ``explicit=None`` decides by :meth:`_explicit_pays_off` (an implicit solve then forms
        the blocks once they have paid off); ``False`` keeps the implicit solve. Cached on this
        solver by the mask's bytes and ``explicit``.
        """
        key = (np.packbits(mask).tobytes(), mask.size, explicit)
        hit = self._interfaces.get(key)
        if hit is not None:
            self._interfaces.move_to_end(key)
        else:
            if explicit is None:
                use_explicit, switch_after = self._explicit_pays_off(mask)
            else:
                use_explicit, switch_after = bool(explicit), None
            hit = (ExplicitInterfaceSolve(self, mask.copy()) if use_explicit
                   else ImplicitInterfaceSolve(self, mask.copy(), switch_after=switch_after))
            self._interfaces[key] = hit
            if len(self._interfaces) > MAX_INTERFACES:     # e.g. one per active set of a contact solve:
                self._interfaces.popitem(last=False)        # their dense blocks must not pile up
        return hit

    def space_solve(self, r: np.ndarray, space, weights: np.ndarray, mask: np.ndarray,
                    explicit: bool | None = None) -> np.ndarray:
        """gather_w(A~^{-1} scatter_w(r)) in a space of continuous values on an interface.

        Convenience for ``interface(mask, explicit).space_operator(space, weights).apply(r)``
        (the operator cached by the space's ``key`` and the weights' bytes); hold the
        operator of :meth:`InterfaceSolve.space_operator` where it is applied repeatedly.
        """
        iface = self.interface(mask, explicit)
        key = (space_key(space), np.asarray(weights).tobytes())
        op = iface.space_operators.get(key)
        if op is None:
            op = iface.space_operators[key] = iface.space_operator(space, weights)
        return op.apply(r)

    def solve_interface(self, b: np.ndarray, mask: np.ndarray, explicit: bool | None = None) -> np.ndarray:
        """:meth:`solve` for a right-hand side supported on ``mask`` (zero on every other entry),
        returning the solution on ``mask`` only (zero elsewhere); see :meth:`interface`."""
        return self.interface(mask, explicit).solve(b)


class InterfaceSolve:
    """A~^{-1} of a :class:`PrimalConstrainedSolver` on an interface ``mask`` (base class).

    Attributes
    ----------
    solver : PrimalConstrainedSolver
    mask : ndarray of bool, shape (n_W,)
    explicit : bool
    space_operators : dict
        Space operators handed out by :meth:`PrimalConstrainedSolver.space_solve`.
    """

    explicit = False

    def __init__(self, solver: PrimalConstrainedSolver, mask: np.ndarray) -> None:
        self.solver = solver
        self.mask = mask
        self.space_operators: dict = {}

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A~^{-1} b for b supported on the mask, returned on the mask (zero elsewhere)."""
        raise NotImplementedError

    def space_operator(self, space, weights: np.ndarray):
        """An object whose ``apply(r)`` is gather_w(A~^{-1} scatter_w(r)) in ``space``.

        scatter_w puts ``weights * r[pos]`` on the W positions ``space.idx``, gather_w
        sums ``weights`` times the copies (R_D^T A~^{-1} R_D of BDDC when ``weights`` are
        the delta-dagger scalings). ``space`` (with ``idx``, ``pos``, ``n``, see
        :meth:`DirichletSchur.space_matvec`) must lie in the mask; no W vector is formed
        by the explicit variant.
        """
        raise NotImplementedError


class ImplicitInterfaceSolve(InterfaceSolve):
    """Interface solves through the full batched :meth:`PrimalConstrainedSolver.solve`.

    With ``switch_after`` (the dense blocks' setup cost in implicit applications, from
    :meth:`PrimalConstrainedSolver._explicit_pays_off`), the blocks are formed once that many
    applications (solves and space-operator applications together) have been made, and every
    later one goes through them: the rent-or-buy rule, so a long run (the hundreds of face-solve
    iterations of the active set method) pays at most twice the better of the two, and a short
    one never pays the setup.
    """

    def __init__(self, solver: PrimalConstrainedSolver, mask: np.ndarray,
                 switch_after: float | None = None) -> None:
        super().__init__(solver, mask)
        self.switch_after = switch_after
        self.applications = 0
        self.explicit_solve: ExplicitInterfaceSolve | None = None

    @property
    def explicit(self) -> bool:            # type: ignore[override]
        """Whether the dense blocks are in use (after the switch)."""
        return self.explicit_solve is not None

    def switched(self) -> ExplicitInterfaceSolve | None:
        """Count one application; the explicit solve once the blocks have paid off (else None)."""
        if self.explicit_solve is None and self.switch_after is not None:
            self.applications += 1
            if self.applications > self.switch_after:
                log.debug("PrimalConstrainedSolver: dense interface blocks formed after %d implicit "
                          "applications", self.applications - 1)
                self.explicit_solve = ExplicitInterfaceSolve(self.solver, self.mask)
        return self.explicit_solve

    def solve(self, b: np.ndarray) -> np.ndarray:
        explicit = self.switched()
        if explicit is not None:
            return explicit.solve(b)
        return np.where(self.mask, self.solver.solve(np.where(self.mask, b, 0.0)), 0.0)

    def space_operator(self, space, weights: np.ndarray) -> ImplicitSpaceSolve:
        return ImplicitSpaceSolve(self, space, weights)


class ImplicitSpaceSolve:
    """Scatter, the implicit solve, gather (see :meth:`InterfaceSolve.space_operator`); after the
    interface's switch, its explicit space operator."""

    def __init__(self, interface: ImplicitInterfaceSolve, space, weights: np.ndarray) -> None:
        self.interface, self.space, self.weights = interface, space, weights
        self._explicit_op: ExplicitSpaceSolve | None = None

    def apply(self, r: np.ndarray) -> np.ndarray:
        explicit = self.interface.switched()
        if explicit is not None:
            if self._explicit_op is None:
                self._explicit_op = explicit.space_operator(self.space, self.weights)
            return self._explicit_op.apply(r)
        space, weights, solver = self.space, self.weights, self.interface.solver
        w = np.zeros(solver.sub.n_W)
        w[space.idx] = weights * r[space.pos]
        x = solver.solve(w)
        return np.bincount(space.pos, weights=weights * x[space.idx], minlength=space.n)


@dataclass
class CoarseBlock:
    """Psi on the interface entries D of one block group, shared by its members.

    ``psi`` (n_d, p_max): the rows of Psi = A_rr^{-1} A_rPi on D; ``coarse_index``
    (p_max, n_members): coarse dof of each member's primal column (n_primal: none).
    """

    psi: np.ndarray
    coarse_index: np.ndarray


@dataclass
class InterfaceBlocks:
    """The dense interface blocks (A_rr^{-1})_{DD} on D = r & mask and the coarse coupling on D.

    Either ``coarse`` (one :class:`CoarseBlock` per group of ``blocks``, when Psi on D is shared by
    the members of each group) or the sparse ``psi`` / ``psi_T`` rows of Psi on D; neither
    without primal unknowns.
    """

    blocks: DenseBlocks
    psi: sp.csr_matrix | None = None
    psi_T: sp.csr_matrix | None = None
    coarse: list[CoarseBlock] | None = None
    coarse_flat: np.ndarray | None = None           # all coarse indices of ``coarse``, group by group


class ExplicitInterfaceSolve(InterfaceSolve):
    """Interface solves with dense blocks (A_rr^{-1})_{DD} = S_DD^{-1} on D = r & mask.

    Formed on first use from the existing factorizations (no new factorization), so one
    application costs one GEMM per group of the interface size plus the coarse solve.
    """

    explicit = True

    def __init__(self, solver: PrimalConstrainedSolver, mask: np.ndarray) -> None:
        super().__init__(solver, mask)
        self._blocks: InterfaceBlocks | None = None

    @property
    def blocks(self) -> InterfaceBlocks:
        """The dense interface blocks (formed on first use)."""
        if self._blocks is None:
            self._blocks = self._build_blocks()
        return self._blocks

    def _build_blocks(self) -> InterfaceBlocks:
        solver, mask = self.solver, self.mask
        blocks = []
        coarse: list[CoarseBlock] | None = [] if solver.n_primal else None
        work: list[tuple[_Group, list[int], np.ndarray]] = []
        for g in solver.rr.groups:
            pattern = mask[g.index]                             # (n_loc, n_members)
            by_pattern: dict[bytes, list[int]] = {}
            for j in range(pattern.shape[1]):
                by_pattern.setdefault(pattern[:, j].tobytes(), []).append(j)
            for members in by_pattern.values():
                d = np.flatnonzero(pattern[:, members[0]])
                if d.size:
                    work.append((g, members, d))
        # unit columns on the interface entries D; one multi-column solve for all batched subdomains
        rhs = [(g.factor, sp.csc_matrix((np.ones(d.size), (d, np.arange(d.size))),
                                        shape=(g.index.shape[0], d.size)), d) for g, _, d in work]
        for (g, members, d), X in zip(work, solve_many(rhs)):
            blocks.append((0.5 * (X + X.T), g.index[d][:, members], g.inv_rho[members]))
            # Psi on D: shared by the members (same template, r set and primal set), with the
            # coarse dof of each member's primal column (n_primal: none)
            if coarse is not None:
                psi = solver.Psi[g.index[d][:, members]]               # (n_d, n_members, p_max)
                if np.array_equal(psi, np.broadcast_to(psi[:, :1], psi.shape)):
                    cc = solver.coarse_cols[g.members[members]].T        # (p_max, n_members)
                    coarse.append(CoarseBlock(np.ascontiguousarray(psi[:, 0]),
                                              np.where(cc >= 0, cc, solver.n_primal)))
                else:
                    coarse = None
        dense = DenseBlocks(blocks)
        if not solver.n_primal:
            return InterfaceBlocks(dense)
        if coarse is not None and len(coarse) > GROUPS_LOOP_MAX:
            coarse = None       # many groups (a general mesh): the sparse rows of Psi, no loop over the groups
        if coarse is not None:
            flat = (np.concatenate([c.coarse_index.ravel() for c in coarse]) if coarse
                    else np.zeros(0, dtype=np.int64))
            return InterfaceBlocks(dense, coarse=coarse, coarse_flat=flat)
        psi_rows = solver.Psi_global[dense.flat].tocsr()
        return InterfaceBlocks(dense, psi=psi_rows, psi_T=psi_rows.T.tocsr())

    def coarse_step(self, bs: np.ndarray, xs: np.ndarray, b_pi: np.ndarray) -> np.ndarray:
        """The coarse part of A~^{-1} on the interface blocks (shared by the two interface solves).

        ``bs``: the right-hand side on the blocks' entries; ``xs``: A_rr^{-1} of it there, corrected
        in place by -Psi u_Pi; ``b_pi`` (n_primal + 1,): the primal right-hand side (last slot a
        sink). Returns u_Pi with a trailing zero (``u_ext``).
        """
        solver, iface_blocks = self.solver, self.blocks
        dense = iface_blocks.blocks
        b_pi = b_pi.astype(np.float64, copy=False)      # a bincount of no entries is an int array
        if iface_blocks.coarse is not None:       # b_pi -= sum_i R_Pi^T Psi_D^T bs (dense per group)
            parts = []
            for (A, off, n, n_m, _), coarse_block in zip(dense.parts, iface_blocks.coarse):
                parts.append((coarse_block.psi.T @ bs[off:off + n * n_m].reshape(n, n_m)).ravel())
            if parts:
                b_pi -= np.bincount(iface_blocks.coarse_flat, weights=np.concatenate(parts), minlength=b_pi.size)
        else:
            b_pi[:-1] -= iface_blocks.psi_T @ bs
        b_pi = b_pi[:-1]
        b_pi[solver.pinned] = 0.0
        u_ext = np.append(solver.coarse.solve(b_pi), 0.0)
        if iface_blocks.coarse is not None:       # xs -= Psi_D u_Pi (dense per group)
            for (A, off, n, n_m, _), coarse_block in zip(dense.parts, iface_blocks.coarse):
                out = xs[off:off + n * n_m].reshape(n, n_m)
                out -= coarse_block.psi @ u_ext[coarse_block.coarse_index]
        else:
            xs -= iface_blocks.psi @ u_ext[:-1]
        return u_ext

    def solve(self, b: np.ndarray) -> np.ndarray:
        solver = self.solver
        dense = self.blocks.blocks
        bs = b[dense.flat]
        xs = dense.apply(bs)
        x = np.zeros(solver.sub.n_W)
        if solver.n_primal:
            b_pi = np.bincount(solver.coarse_of_W[solver.primal], weights=b[solver.primal],
                               minlength=solver.n_primal + 1)
            u_ext = self.coarse_step(bs, xs, b_pi)
            x[solver.primal] = u_ext[solver.coarse_of_W[solver.primal]]
        x[dense.flat] = xs
        return np.where(self.mask, x, 0.0)

    def space_operator(self, space, weights: np.ndarray) -> ExplicitSpaceSolve:
        solver = self.solver
        dense = self.blocks.blocks
        look = np.full(solver.sub.n_W, -1, dtype=np.int64)
        look[space.idx] = np.arange(space.idx.size)
        ent = look[dense.flat]
        sel = np.flatnonzero(ent >= 0)
        index_in = np.full(dense.flat.size, space.n, dtype=np.int64)
        index_in[sel] = space.pos[ent[sel]]
        weight_in = np.zeros(dense.flat.size)
        weight_in[sel] = weights[ent[sel]]
        primal_entries = look[np.flatnonzero(solver.primal)]
        primal_entries = primal_entries[primal_entries >= 0]
        # entries outside the space carry weight 0 and land in the extra slot space.n
        return ExplicitSpaceSolve(interface=self, n=space.n, index_in=index_in, weight_in=weight_in,
                                  primal_pos=space.pos[primal_entries], primal_weight=weights[primal_entries],
                                  primal_coarse=solver.coarse_of_W[space.idx[primal_entries]])


@dataclass
class ExplicitSpaceSolve:
    """gather_w(A~^{-1} scatter_w(r)) on compact index maps (see :meth:`InterfaceSolve.space_operator`).

    Attributes
    ----------
    interface : ExplicitInterfaceSolve
    n : int
        Dimension of the space.
    index_in : ndarray of int, shape (blocks.size,)
        Space index of every block entry (``n`` outside the space).
    weight_in : ndarray, shape (blocks.size,)
        Weight of every block entry (0 outside the space).
    primal_pos, primal_weight, primal_coarse : ndarray, shape (n_primal_entries,)
        Space index, weight and coarse dof of the primal entries in the space.
    """

    interface: ExplicitInterfaceSolve
    n: int
    index_in: np.ndarray
    weight_in: np.ndarray
    primal_pos: np.ndarray
    primal_weight: np.ndarray
    primal_coarse: np.ndarray

    def apply(self, r: np.ndarray) -> np.ndarray:
        iface = self.interface
        solver = iface.solver
        r_ext = np.concatenate([r, np.zeros(1)])
        xs = r_ext[self.index_in]
        xs *= self.weight_in
        ys = iface.blocks.blocks.apply(xs)
        out = None
        if solver.n_primal:
            b_pi = np.bincount(self.primal_coarse, weights=r[self.primal_pos] * self.primal_weight,
                               minlength=solver.n_primal + 1)
            u_ext = iface.coarse_step(xs, ys, b_pi)
            out = np.bincount(self.primal_pos, weights=u_ext[self.primal_coarse] * self.primal_weight,
                              minlength=self.n)
        ys *= self.weight_in
        y = np.bincount(self.index_in, weights=ys, minlength=self.n + 1)[:-1]      # slot n: outside
        return y if out is None else y + out
