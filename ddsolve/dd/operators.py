"""Subdomain-based operators shared by the FETI, FETI-DP and BDDC solvers.

All operators act on W vectors (see :mod:`ddsolve.dd.substructure`) and are
applied through batched subdomain solves; none forms a global dense matrix.

Operators that only act on the subdomain interfaces can instead use small
dense *local* matrices formed once from the existing factorizations (one per
distinct subdomain, shared by identical ones): the local Schur complements
S_t (:meth:`DirichletSchur.matvec`, ``explicit``), their harmonic extensions
K_II^{-1} K_IG (:meth:`DirichletSchur.interior_solution`) and the interface
block of the primal-constrained inverse (:meth:`PrimalConstrainedSolver.solve_interface`).
One application is then one GEMM per group of the size of the local
interface (O(H/h) unknowns) instead of interior solves with O((H/h)^2)
unknowns and products with K_W. ``space_matvec`` / ``space_solve`` apply them
directly between compact spaces of interface values (no W vectors).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .local import BatchedSolver, DenseBlocks
from .substructure import Substructures

log = logging.getLogger(__name__)

#: ``explicit=None`` (auto) forms the local Schur complements explicitly when their setup
#: (one local solve per interface unknown of each distinct subdomain) costs at most this
#: many applications of the implicit operator (one batched solve each).
EXPLICIT_SETUP_MATVECS = 16
#: Largest local interface (or primal-free interface) block formed explicitly (dense, n^2 doubles).
EXPLICIT_MAX_BLOCK = 4000
#: Memory budget of the explicit harmonic extensions K_II^{-1} K_IG kept by an explicit
#: :class:`DirichletSchur` (dense n_I x n_G per group) for :meth:`DirichletSchur.interior_solution`.
EXPLICIT_EXTENSION_BYTES = 512 * 2**20


@dataclass
class _SchurGroup:
    """Subdomains sharing one explicit local Schur complement: template, local interior/interface sets."""

    template: int
    interior_local: np.ndarray
    gamma_local: np.ndarray
    members: list[int]


@dataclass
class ExtensionBlock:
    """Explicit harmonic extension K_II^{-1} K_IG of one group and the W positions of its members."""

    extension: np.ndarray           # (n_i, n_g)
    gamma_index: np.ndarray         # (n_g, n_members)
    interior_index: np.ndarray      # (n_i, n_members)


@dataclass
class HarmonicExtensions:
    """All explicit harmonic extensions, with the flat W positions of their interface and interior entries."""

    blocks: list[ExtensionBlock]
    flat_gamma: np.ndarray
    flat_interior: np.ndarray


@dataclass
class _InteriorLoad:
    """The last interior load A_II^{-1} f (``source`` the array passed, ``values`` its copy)."""

    source: np.ndarray
    values: np.ndarray
    solution: np.ndarray


@dataclass
class SchurSpaceMatvec:
    """gather_out(S scatter_in(u)) on compact index maps (:meth:`DirichletSchur.space_matvec`).

    Attributes
    ----------
    blocks : DenseBlocks
        The local Schur complements of the subdomains touching both spaces.
    index_in : ndarray of int, shape (blocks.size,)
        Index into the concatenated input values (their total size: the appended zero).
    index_out : ndarray of int, shape (blocks.size,)
        Output index of every block entry (-1 outside the output space).
    out_select : ndarray of int or None
        Block entries inside the output space (None: all).
    n_out : int
    """

    blocks: DenseBlocks
    index_in: np.ndarray
    index_out: np.ndarray
    out_select: np.ndarray | None
    n_out: int

    def apply(self, us: list[np.ndarray]) -> np.ndarray:
        u_ext = np.concatenate(list(us) + [np.zeros(1)])
        ys = self.blocks.apply(u_ext[self.index_in])
        if self.out_select is None:
            return np.bincount(self.index_out, weights=ys, minlength=self.n_out)
        return np.bincount(self.index_out[self.out_select], weights=ys[self.out_select], minlength=self.n_out)


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
    explicit : bool, optional
        Apply S through explicitly formed dense local Schur complements
        S_t = K_GG - K_GI K_II^{-1} K_IG, one per distinct (template, interior
        set, interface set), scaled by rho_i: one GEMM per group of the size of
        the local *interface* instead of two sparse products with K_W and an
        interior solve. Formed on the first :meth:`matvec` from the existing
        interior factorizations (no new factorization). ``None`` (default):
        explicit when that setup costs at most ``EXPLICIT_SETUP_MATVECS``
        implicit applications and no block exceeds ``EXPLICIT_MAX_BLOCK``.
        The result is the same operator up to rounding.
    """

    def __init__(self, sub: Substructures, gamma_mask: np.ndarray, cache: dict,
                 exclude: np.ndarray | None = None, explicit: bool | None = None) -> None:
        self.sub = sub
        self.gamma = gamma_mask
        self.interior = ~gamma_mask if exclude is None else ~gamma_mask & ~exclude
        self.II = BatchedSolver(sub, self.interior, cache)
        self._cache = cache
        self._explicit_option = explicit
        self._blocks: DenseBlocks | None | bool = None      # None: not decided yet; False: implicit
        self._space_operators: dict[tuple, SchurSpaceMatvec] = {}     # by the spaces' keys
        self._extensions: HarmonicExtensions | None = None  # explicit harmonic extensions (with explicit S)
        self._last_load: _InteriorLoad | None = None

    def _explicit_groups(self) -> list[_SchurGroup]:
        """Subdomains grouped by (template, interior set, interface set): one dense S_t each."""
        sub = self.sub
        groups: dict[bytes, _SchurGroup] = {}
        for s in range(sub.n_sub):
            lo, hi = sub.offsets[s], sub.offsets[s + 1]
            loc = sub.local_index[lo:hi]
            loc_g = loc[self.gamma[lo:hi]]
            if loc_g.size == 0:
                continue
            loc_i = loc[self.interior[lo:hi]]
            t = int(sub.template[s])
            key = (t.to_bytes(8, "little") + loc_i.size.to_bytes(8, "little")
                   + loc_i.astype(np.int64).tobytes() + loc_g.astype(np.int64).tobytes())
            if key not in groups:
                groups[key] = _SchurGroup(template=t, interior_local=loc_i, gamma_local=loc_g, members=[])
            groups[key].members.append(s)
        return list(groups.values())

    def _build_explicit(self) -> DenseBlocks | bool:
        groups = self._explicit_groups()
        setup_cols = sum(g.gamma_local.size for g in groups)
        biggest = max((g.gamma_local.size for g in groups), default=0)
        explicit = self._explicit_option
        if explicit is None:
            explicit = (setup_cols <= EXPLICIT_SETUP_MATVECS * max(self.sub.n_sub, 1)
                        and biggest <= EXPLICIT_MAX_BLOCK)
        if not explicit:
            return False
        sub = self.sub
        blocks = []
        keep_ext = sum(g.interior_local.size * g.gamma_local.size for g in groups) * 8 <= EXPLICIT_EXTENSION_BYTES
        ext: list[ExtensionBlock] = []
        for group in groups:
            t, loc_i, loc_g, members = group.template, group.interior_local, group.gamma_local, group.members
            K = sub.stiffness[t]
            Kg = K[loc_g]
            S = Kg[:, loc_g].toarray()
            members_arr = np.asarray(members)
            index = np.stack([sub.position(s, loc_g) for s in members_arr], axis=1)
            if loc_i.size:
                key = t.to_bytes(8, "little") + loc_i.astype(np.int64).tobytes()
                factor = self._cache[key]           # built by self.II
                K_ig = K[loc_i][:, loc_g].toarray()
                X = factor.solve(K_ig)              # harmonic extension K_II^{-1} K_IG (rho cancels)
                S -= K_ig.T @ X
                S = 0.5 * (S + S.T)
                if keep_ext:
                    index_i = np.stack([sub.position(s, loc_i) for s in members_arr], axis=1)
                    ext.append(ExtensionBlock(np.ascontiguousarray(X), index, index_i))
            blocks.append((S, index, sub.rho[members_arr]))
        if keep_ext:
            self._extensions = HarmonicExtensions(
                blocks=ext,
                flat_gamma=np.concatenate([e.gamma_index.ravel() for e in ext]) if ext else np.zeros(0, np.int64),
                flat_interior=np.concatenate([e.interior_index.ravel() for e in ext]) if ext else np.zeros(0, np.int64))
        log.debug("DirichletSchur: %d explicit local Schur complements (largest %d)", len(blocks), biggest)
        return DenseBlocks(blocks)

    def _interior_load(self, f: np.ndarray) -> np.ndarray:
        """A_II^{-1} f_I (zero off the interior), cached for the last f (same array, same values)."""
        hit = self._last_load
        if hit is not None and hit.source is f and np.array_equal(hit.values, f):
            return hit.solution
        z = self.II.solve(f)
        self._last_load = _InteriorLoad(source=f, values=f.copy(), solution=z)
        return z

    @property
    def extensions(self) -> HarmonicExtensions | None:
        """The explicit harmonic extensions K_II^{-1} K_IG (None: implicit, or over the memory budget)."""
        return self._extensions if self.explicit else None

    @property
    def explicit(self) -> bool:
        """Whether :meth:`matvec` uses explicit local Schur complements (decided on first use)."""
        if self._blocks is None:
            self._blocks = self._build_explicit()
        return self._blocks is not False

    def space_matvec(self, u, space_in, space_out) -> np.ndarray:
        """gather_out(S scatter_in(u)) between spaces of continuous interface values.

        Parameters
        ----------
        u : ndarray or sequence of ndarray
            Values in ``space_in`` (one array per space if a sequence).
        space_in : space or sequence of spaces
            Objects with ``idx`` (W positions), ``pos`` (compact index of each
            position) and ``n`` (dimension), e.g. the hybrid's ``InterfaceSpace``
            (its ``key``, when present, keys the cache);
            scatter_in puts ``u[pos]`` on every W position ``idx`` (the spaces
            of a sequence must not overlap). Entries must lie on Gamma.
        space_out : space
            gather_out sums the copies of the result on its positions.

        Returns
        -------
        ndarray, shape (space_out.n,)

        Notes
        -----
        With explicit local Schur complements no W vector is formed: only the
        subdomains that touch both spaces are applied, on compact index maps
        built once per (spaces) pair.
        """
        spaces = list(space_in) if isinstance(space_in, (list, tuple)) else [space_in]
        us = list(u) if isinstance(space_in, (list, tuple)) else [u]
        if not self.explicit:
            w = np.zeros(self.sub.n_W)
            for sp_, v in zip(spaces, us):
                w[sp_.idx] = v[sp_.pos]
            y = self.matvec(w)
            return np.bincount(space_out.pos, weights=y[space_out.idx], minlength=space_out.n)
        key = tuple(space_key(x) for x in spaces) + (space_key(space_out),)
        op = self._space_operators.get(key)
        if op is None:
            op = self._space_operators[key] = self._build_space_operator(spaces, space_out)
        return op.apply(us)

    def _build_space_operator(self, spaces, space_out) -> SchurSpaceMatvec:
        n_W = self.sub.n_W
        lin = np.full(n_W, -1, dtype=np.int64)
        off = 0
        for sp_ in spaces:
            lin[sp_.idx] = sp_.pos + off
            off += sp_.n
        lout = np.full(n_W, -1, dtype=np.int64)
        lout[space_out.idx] = space_out.pos
        parts = []
        for A, o, n, n_m, scale in self._blocks.parts:
            index = self._blocks.flat[o:o + n * n_m].reshape(n, n_m)
            keep = (lin[index] >= 0).any(axis=0) & (lout[index] >= 0).any(axis=0)
            if keep.any():
                parts.append((A, index[:, keep], scale[keep]))
        blocks = DenseBlocks(parts)
        cin = lin[blocks.flat]
        cin[cin < 0] = off                      # the zero appended to u
        cout = lout[blocks.flat]
        osel = None if (cout >= 0).all() else np.flatnonzero(cout >= 0)
        return SchurSpaceMatvec(blocks=blocks, index_in=cin, index_out=cout, out_select=osel, n_out=space_out.n)

    def matvec(self, w: np.ndarray) -> np.ndarray:
        """S w for a W vector (read on Gamma); result is zero off Gamma."""
        if self.explicit:
            y = np.zeros(self.sub.n_W)
            blocks = self._blocks
            y[blocks.flat] = blocks.apply(w[blocks.flat])
            return y
        w = np.where(self.gamma, w, 0.0)
        t = self.sub.K_W @ w
        z = self.II.solve(t)
        y = t - self.sub.K_W @ z
        return np.where(self.gamma, y, 0.0)

    def harmonic_extension_rhs(self, f: np.ndarray) -> np.ndarray:
        """g = f_Gamma - A_GI A_II^{-1} f_I (condensed load), zero off Gamma."""
        z = self._interior_load(f)
        return np.where(self.gamma, f - self.sub.K_W @ z, 0.0)

    def interior_solution(self, f: np.ndarray, w_gamma: np.ndarray) -> np.ndarray:
        """Complete interface values by u_I = A_II^{-1} (f_I - A_IG w_Gamma); returns a full W vector."""
        w = np.where(self.gamma, w_gamma, 0.0)
        if self.explicit and self._extensions is not None:
            # u_I = A_II^{-1} f_I - (A_II^{-1} A_IG) w_G: the cached interior load and one GEMM per group
            ext = self._extensions
            wg = w[ext.flat_gamma]
            out = np.empty(ext.flat_interior.size)
            og = oi = 0
            for block in ext.blocks:
                n_g, n_m = block.gamma_index.shape
                n_i = block.interior_index.shape[0]
                np.matmul(block.extension, wg[og:og + n_g * n_m].reshape(n_g, n_m),
                          out=out[oi:oi + n_i * n_m].reshape(n_i, n_m))
                og += n_g * n_m
                oi += n_i * n_m
            x = w + self._interior_load(f)
            x[ext.flat_interior] -= out
            return x
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
        for g in self.rr.groups:
            members = g.members
            by_primal: dict[bytes, list[int]] = {}
            for j, s_ in enumerate(members):
                loc_p = sub.local_index[self.table[s_][valid[s_]]]
                by_primal.setdefault(loc_p.astype(np.int64).tobytes(), []).append(j)
            for js in by_primal.values():
                s0 = members[js[0]]
                loc_p = sub.local_index[self.table[s0][valid[s0]]]
                p = loc_p.size
                K = sub.stiffness[int(sub.template[s0])]
                KpP = K[loc_p][:, loc_p].toarray()
                if p:
                    KrP_t = K[g.loc][:, loc_p].toarray()
                    Psi_t = g.factor.solve(KrP_t)
                    S_t = KpP - KrP_t.T @ Psi_t
                    idx = g.index[:, js]                                    # (n_r, n_js)
                    for c in range(p):
                        self.Psi[idx, c] = Psi_t[:, c][:, None]
                else:
                    S_t = KpP
                sel = np.asarray(members)[js]
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
        self._psi_global: sp.csr_matrix | None = None      # Psi as sparse (n_W, n_primal), on first use
        self._psi_global_T: sp.csr_matrix | None = None
        self._interfaces: dict[tuple, InterfaceSolve] = {}  # by (mask bytes, n_W, explicit option)

    def _primal_dofs(self, sub: Substructures, primal_mask: np.ndarray) -> np.ndarray:
        """Sorted global dofs of the primal unknowns (hook: a rank-local ``sub`` sees only its own)."""
        return np.unique(sub.l2g[primal_mask])

    def _assemble_coarse(self, S_PiPi: sp.csr_matrix) -> sp.csr_matrix:
        """The coarse matrix from the subdomains' contributions (hook: summed over ranks in parallel)."""
        return S_PiPi

    @property
    def Psi_global(self) -> sp.csr_matrix:
        """Psi as one sparse (n_W, n_primal) matrix: column c of entry e goes to its coarse dof."""
        if self._psi_global is None:
            sub = self.sub
            entry_cols = self.coarse_cols[sub.sub_of_W] if self.p_max else np.zeros((sub.n_W, 0), dtype=int)
            ok = entry_cols >= 0
            rows = np.broadcast_to(np.arange(sub.n_W)[:, None], ok.shape)[ok]
            P = sp.csr_matrix((self.Psi[ok], (rows, entry_cols[ok])), shape=(sub.n_W, self.n_primal))
            self._psi_global, self._psi_global_T = P, P.T.tocsr()
        return self._psi_global

    @property
    def Psi_global_T(self) -> sp.csr_matrix:
        """Psi^T as sparse (n_primal, n_W)."""
        if self._psi_global_T is None:
            self._psi_global_T = self.Psi_global.T.tocsr()
        return self._psi_global_T

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x = A~^{-1} b for a W vector b; primal copies of b are summed (assembled).

        Returns a W vector whose primal entries all hold the (continuous) primal value.
        """
        br = np.where(self.r, b, 0.0)
        x = self.rr.solve(br)
        if self.n_primal == 0:
            return x
        b_pi = np.bincount(self.coarse_of_W[self.primal], weights=b[self.primal], minlength=self.n_primal)
        b_pi -= self.Psi_global_T @ br                 # assembled Psi^T b_r
        b_pi[self.pinned] = 0.0
        u_pi = self.coarse.solve(b_pi)
        x -= self.Psi_global @ u_pi
        x[self.primal] = u_pi[self.coarse_of_W[self.primal]]
        return x

    def _explicit_pays_off(self, mask: np.ndarray) -> bool:
        """Whether the dense interface blocks of ``mask`` pay off (the rule of ``DirichletSchur``).

        Forming them costs one local solve per interface unknown of each distinct
        (template, r set, interface pattern); one implicit :meth:`solve` costs one per
        subdomain. Explicit when the former is at most ``EXPLICIT_SETUP_MATVECS`` of the
        latter and no block exceeds ``EXPLICIT_MAX_BLOCK``. With few, large subdomains
        (H/h = 128 or more) the implicit solve is cheaper over a solve.
        """
        cols, biggest = 0, 0
        for g in self.rr.groups:
            pattern = np.ascontiguousarray(np.packbits(mask[g.index], axis=0).T)   # one row per member
            rows = pattern.view(np.dtype((np.void, pattern.shape[1]))).ravel()
            _, first = np.unique(rows, return_index=True)                           # distinct patterns
            n_d = np.count_nonzero(mask[g.index][:, first], axis=0)
            cols, biggest = cols + int(n_d.sum()), max(biggest, int(n_d.max(initial=0)))
        explicit = cols <= EXPLICIT_SETUP_MATVECS * max(self.sub.n_sub, 1) and biggest <= EXPLICIT_MAX_BLOCK
        log.debug("PrimalConstrainedSolver: %s interface blocks (%d setup columns, largest %d)",
                  "explicit" if explicit else "implicit", cols, biggest)
        return explicit

    def interface(self, mask: np.ndarray, explicit: bool | None = None) -> InterfaceSolve:
        """A~^{-1} restricted to the interface ``mask`` (explicit dense blocks or implicit solves).

        ``mask`` (an interface: every interior entry of the subdomains is outside it).
        ``explicit=None`` decides by :meth:`_explicit_pays_off`. Cached on this solver by the
        mask's bytes and ``explicit``.
        """
        key = (np.packbits(mask).tobytes(), mask.size, explicit)
        hit = self._interfaces.get(key)
        if hit is None:
            use_explicit = self._explicit_pays_off(mask) if explicit is None else bool(explicit)
            hit = (ExplicitInterfaceSolve if use_explicit else ImplicitInterfaceSolve)(self, mask.copy())
            self._interfaces[key] = hit
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


def space_key(space) -> tuple:
    """Cache key of a space (``idx``, ``pos``, ``n``): its ``key`` attribute, else its index bytes."""
    key = getattr(space, "key", None)
    if key is not None:
        return key
    return (np.asarray(space.idx).tobytes(), np.asarray(space.pos).tobytes(), int(space.n))


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
    """Interface solves through the full batched :meth:`PrimalConstrainedSolver.solve`."""

    def solve(self, b: np.ndarray) -> np.ndarray:
        return np.where(self.mask, self.solver.solve(np.where(self.mask, b, 0.0)), 0.0)

    def space_operator(self, space, weights: np.ndarray) -> ImplicitSpaceSolve:
        return ImplicitSpaceSolve(self.solver, space, weights)


class ImplicitSpaceSolve:
    """Scatter, the implicit solve, gather (see :meth:`InterfaceSolve.space_operator`)."""

    def __init__(self, solver: PrimalConstrainedSolver, space, weights: np.ndarray) -> None:
        self.solver, self.space, self.weights = solver, space, weights

    def apply(self, r: np.ndarray) -> np.ndarray:
        space, weights = self.space, self.weights
        w = np.zeros(self.solver.sub.n_W)
        w[space.idx] = weights * r[space.pos]
        x = self.solver.solve(w)
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
        for g in solver.rr.groups:
            n_loc = g.index.shape[0]
            pattern = mask[g.index]                             # (n_loc, n_members)
            by_pattern: dict[bytes, list[int]] = {}
            for j in range(pattern.shape[1]):
                by_pattern.setdefault(pattern[:, j].tobytes(), []).append(j)
            for members in by_pattern.values():
                d = np.flatnonzero(pattern[:, members[0]])
                if d.size == 0:
                    continue
                E = np.zeros((n_loc, d.size))
                E[d, np.arange(d.size)] = 1.0
                X = g.factor.solve(E)[d]
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


class PairJump:
    """A jump operator between pairs of entries of one vector space, given by index arrays.

    Row k of B is ``+c1_k`` at entry ``first[k]`` and ``-c2_k`` at entry ``second[k]``:
    the jump (B u)_k = u_first - u_second (coefficients None), or a scaled jump B_D with
    each copy weighted by the other copy's weight (the delta-dagger / rho scaling of
    Section 2.5 at the level of bodies, ``coef_first`` = weight of the second copy).

    Parameters
    ----------
    first, second : ndarray of int, shape (n_rows,)
        Entry of the first and of the second copy of every pair.
    n : int
        Dimension of the vector space the entries index.
    coef_first, coef_second : ndarray, shape (n_rows,), optional
        Coefficients of the two copies (None: 1).
    """

    def __init__(self, first: np.ndarray, second: np.ndarray, n: int,
                 coef_first: np.ndarray | None = None, coef_second: np.ndarray | None = None) -> None:
        self.first, self.second, self.n = first, second, int(n)
        self.coef_first, self.coef_second = coef_first, coef_second
        self.shape = (first.size, self.n)

    def matvec(self, u: np.ndarray) -> np.ndarray:
        """B u, shape (n,) -> (n_rows,)."""
        if self.coef_first is None:
            return u[self.first] - u[self.second]
        return self.coef_first * u[self.first] - self.coef_second * u[self.second]

    def rmatvec(self, lam: np.ndarray) -> np.ndarray:
        """B^T lam, shape (n_rows,) -> (n,)."""
        if self.coef_first is None:
            return (np.bincount(self.first, weights=lam, minlength=self.n)
                    - np.bincount(self.second, weights=lam, minlength=self.n))
        return (np.bincount(self.first, weights=self.coef_first * lam, minlength=self.n)
                - np.bincount(self.second, weights=self.coef_second * lam, minlength=self.n))


def scaled_jump(B_D, schur):
    """The Dirichlet preconditioner pattern lam -> B_D S B_D^T lam (Section 2.5).

    Used for the FETI/FETI-DP/FETI-FETI preconditioner M_D^{-1} = B_D S B_D^T, the
    multiplier block Z B_{Gamma_OL,D} S~_OL B_{Gamma_OL,D}^T Z of the hybrid's (4.11)
    and the preconditioner B^_D S^_c B^_D^T of the active set method (Chapter 5).

    Parameters
    ----------
    B_D : sparse matrix or :class:`PairJump`, shape (n_lambda, n)
        Scaled jump operator.
    schur : callable
        (n,) -> (n,): the (possibly inexact) Schur complement S.

    Returns
    -------
    callable
        (n_lambda,) -> (n_lambda,).
    """
    if sp.issparse(B_D):
        B_DT = B_D.T.tocsr()

        def apply(lam: np.ndarray) -> np.ndarray:
            return B_D @ schur(B_DT @ lam)
    else:
        def apply(lam: np.ndarray) -> np.ndarray:
            return B_D.matvec(schur(B_D.rmatvec(lam)))
    return apply


def linear_operator(n: int, matvec) -> spla.LinearOperator:
    """Wrap a matvec as a symmetric scipy LinearOperator of shape (n, n)."""
    return spla.LinearOperator((n, n), matvec=matvec, rmatvec=matvec, dtype=float)
