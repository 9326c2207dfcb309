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
        self._explicit_opt = explicit
        self._blocks: DenseBlocks | None | bool = None      # None: not decided yet; False: implicit
        self._space_ops: dict = {}
        self._ext: tuple | None = None          # explicit harmonic extensions (with explicit S)
        self._zf: tuple | None = None

    def _explicit_groups(self) -> dict:
        sub = self.sub
        groups: dict[bytes, tuple[int, np.ndarray, np.ndarray, list[int]]] = {}
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
                groups[key] = (t, loc_i, loc_g, [])
            groups[key][3].append(s)
        return groups

    def _build_explicit(self) -> DenseBlocks | bool:
        groups = self._explicit_groups()
        setup_cols = sum(g[2].size for g in groups.values())
        biggest = max((g[2].size for g in groups.values()), default=0)
        explicit = self._explicit_opt
        if explicit is None:
            explicit = (setup_cols <= EXPLICIT_SETUP_MATVECS * max(self.sub.n_sub, 1)
                        and biggest <= EXPLICIT_MAX_BLOCK)
        if not explicit:
            return False
        sub = self.sub
        blocks = []
        keep_ext = sum(g[1].size * g[2].size for g in groups.values()) * 8 <= EXPLICIT_EXTENSION_BYTES
        ext = []
        for t, loc_i, loc_g, members in groups.values():
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
                    ext.append((np.ascontiguousarray(X), index, index_i))
            blocks.append((S, index, sub.rho[members_arr]))
        if keep_ext:
            self._ext = (ext, np.concatenate([e[1].ravel() for e in ext]) if ext else np.zeros(0, np.int64),
                         np.concatenate([e[2].ravel() for e in ext]) if ext else np.zeros(0, np.int64))
        log.debug("DirichletSchur: %d explicit local Schur complements (largest %d)", len(blocks), biggest)
        return DenseBlocks(blocks)

    def _interior_load(self, f: np.ndarray) -> np.ndarray:
        """A_II^{-1} f_I (zero off the interior), cached for the last f (same array, same values)."""
        hit = self._zf
        if hit is not None and hit[0] is f and np.array_equal(hit[1], f):
            return hit[2]
        z = self.II.solve(f)
        self._zf = (f, f.copy(), z)
        return z

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
            position) and ``n`` (dimension), e.g. the hybrid's ``_Space``;
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
        key = tuple(id(x) for x in spaces) + (id(space_out),)
        hit = self._space_ops.get(key)
        if hit is None or any(a is not b for a, b in zip(hit[0], spaces + [space_out])):
            hit = (spaces + [space_out], self._build_space_op(spaces, space_out))
            self._space_ops[key] = hit
        blocks, cin, cout, osel = hit[1]
        u_ext = np.concatenate(us + [np.zeros(1)])
        ys = blocks.apply(u_ext[cin])
        if osel is None:
            return np.bincount(cout, weights=ys, minlength=space_out.n)
        return np.bincount(cout[osel], weights=ys[osel], minlength=space_out.n)

    def _build_space_op(self, spaces, space_out):
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
        return blocks, cin, cout, osel

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
        if self.explicit and self._ext is not None:
            # u_I = A_II^{-1} f_I - (A_II^{-1} A_IG) w_G: the cached interior load and one GEMM per group
            ext, flat_g, flat_i = self._ext
            wg = w[flat_g]
            out = np.empty(flat_i.size)
            og = oi = 0
            for X, index, index_i in ext:
                n_g, n_m = index.shape
                n_i = index_i.shape[0]
                np.matmul(X, wg[og:og + n_g * n_m].reshape(n_g, n_m),
                          out=out[oi:oi + n_i * n_m].reshape(n_i, n_m))
                og += n_g * n_m
                oi += n_i * n_m
            x = w + self._interior_load(f)
            x[flat_i] -= out
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
        self._psi_csr: tuple | None = None       # (Psi, Psi^T) as sparse (n_W, n_primal), on first use
        self._iface: dict[int, tuple] = {}
        self._explicit_iface: dict[int, tuple] = {}
        self._space_ops: dict = {}

    @property
    def _Psi_global(self) -> sp.csr_matrix:
        """Psi as one sparse (n_W, n_primal) matrix: column c of entry e goes to its coarse dof."""
        if self._psi_csr is None:
            sub = self.sub
            entry_cols = self.coarse_cols[sub.sub_of_W] if self.p_max else np.zeros((sub.n_W, 0), dtype=int)
            ok = entry_cols >= 0
            rows = np.broadcast_to(np.arange(sub.n_W)[:, None], ok.shape)[ok]
            P = sp.csr_matrix((self.Psi[ok], (rows, entry_cols[ok])), shape=(sub.n_W, self.n_primal))
            self._psi_csr = (P, P.T.tocsr())
        return self._psi_csr[0]

    @property
    def _Psi_global_T(self) -> sp.csr_matrix:
        self._Psi_global
        return self._psi_csr[1]

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

    def _explicit_interface(self, mask: np.ndarray) -> bool:
        """Whether the dense interface blocks of ``mask`` pay off (the rule of ``DirichletSchur``).

        Forming them costs one local solve per interface unknown of each distinct
        (template, r set, interface pattern); one implicit :meth:`solve` costs one per
        subdomain. Explicit when the former is at most ``EXPLICIT_SETUP_MATVECS`` of the
        latter and no block exceeds ``EXPLICIT_MAX_BLOCK`` (cached per mask). With few,
        large subdomains (H/h = 128 or more) the implicit solve is cheaper over a solve.
        """
        hit = self._explicit_iface.get(id(mask))
        if hit is not None and hit[0] is mask:
            return hit[1]
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
        self._explicit_iface[id(mask)] = (mask, explicit)
        return explicit

    def _interface_blocks(self, mask: np.ndarray) -> tuple:
        """(DenseBlocks of (A_rr^{-1})_{DD}, Psi rows on D, their transpose) for D = r & mask (cached)."""
        hit = self._iface.get(id(mask))
        if hit is not None and hit[0] is mask:
            return hit[1]
        blocks = []
        coarse: list | None = [] if self.n_primal else None
        for g in self.rr.groups:
            n_loc = g.index.shape[0]
            pattern = mask[g.index]                             # (n_loc, n_members)
            keys: dict[bytes, list[int]] = {}
            for j in range(pattern.shape[1]):
                keys.setdefault(pattern[:, j].tobytes(), []).append(j)
            for members in keys.values():
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
                    psi = self.Psi[g.index[d][:, members]]              # (n_d, n_members, p_max)
                    if np.array_equal(psi, np.broadcast_to(psi[:, :1], psi.shape)):
                        cc = self.coarse_cols[g.members[members]].T       # (p_max, n_members)
                        coarse.append((np.ascontiguousarray(psi[:, 0]), np.where(cc >= 0, cc, self.n_primal)))
                    else:
                        coarse = None
        db = DenseBlocks(blocks)
        if not self.n_primal:
            out = (db, None, None, None)
        elif coarse is not None:
            out = (db, None, None, coarse)
        else:
            P = self._Psi_global[db.flat].tocsr()
            out = (db, P, P.T.tocsr(), None)
        self._iface[id(mask)] = (mask, out)
        return out

    def _coarse_rhs(self, db: DenseBlocks, coarse: list, xs: np.ndarray, b_pi: np.ndarray) -> None:
        """b_pi -= sum_i R_Pi^T Psi_D^T xs (dense per group), in place; b_pi has n_primal + 1 slots."""
        parts = []
        for (A, off, n, n_m, _), (psi, cc) in zip(db.parts, coarse):
            parts.append((psi.T @ xs[off:off + n * n_m].reshape(n, n_m)).ravel())
        if parts:
            b_pi -= np.bincount(self._coarse_index(db, coarse), weights=np.concatenate(parts),
                                minlength=b_pi.size)

    @staticmethod
    def _coarse_index(db: DenseBlocks, coarse: list) -> np.ndarray:
        if not hasattr(db, "_cc_flat"):
            db._cc_flat = np.concatenate([cc.ravel() for _, cc in coarse])
        return db._cc_flat

    @staticmethod
    def _coarse_correct(db: DenseBlocks, coarse: list, ys: np.ndarray, u_ext: np.ndarray) -> None:
        """ys -= Psi_D u_Pi (dense per group), in place; u_ext has a zero in slot n_primal."""
        for (A, off, n, n_m, _), (psi, cc) in zip(db.parts, coarse):
            out = ys[off:off + n * n_m].reshape(n, n_m)
            out -= psi @ u_ext[cc]

    def _coarse_step(self, blocks: tuple, bs: np.ndarray, xs: np.ndarray, b_pi: np.ndarray) -> np.ndarray:
        """The coarse part of A~^{-1} on the interface blocks (shared by the two interface solves).

        ``bs``: the right-hand side on the blocks' entries; ``xs``: A_rr^{-1} of it there, corrected
        in place by -Psi u_Pi; ``b_pi`` (n_primal + 1,): the primal right-hand side (last slot a
        sink). Returns u_Pi with a trailing zero (``u_ext``).
        """
        db, P, PT, coarse = blocks
        if coarse is not None:
            self._coarse_rhs(db, coarse, bs, b_pi)
        else:
            b_pi[:-1] -= PT @ bs
        b_pi = b_pi[:-1]
        b_pi[self.pinned] = 0.0
        u_ext = np.append(self.coarse.solve(b_pi), 0.0)
        if coarse is not None:
            self._coarse_correct(db, coarse, xs, u_ext)
        else:
            xs -= P @ u_ext[:-1]
        return u_ext

    def space_solve(self, r: np.ndarray, space, weights: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """gather_w(A~^{-1} scatter_w(r)) in a space of continuous values on an interface.

        scatter_w puts ``weights * r[pos]`` on the W positions ``space.idx``,
        gather_w sums ``weights`` times the copies (R_D^T A~^{-1} R_D of BDDC
        when ``weights`` are the delta-dagger scalings). ``space`` (with
        ``idx``, ``pos``, ``n``, see :meth:`DirichletSchur.space_matvec`) must
        lie in ``mask``, an interface (see :meth:`solve_interface`); no W
        vector is formed.

        Returns
        -------
        ndarray, shape (space.n,)
        """
        if not self._explicit_interface(mask):             # scatter, the implicit solve, gather
            w = np.zeros(self.sub.n_W)
            w[space.idx] = weights * r[space.pos]
            x = self.solve(w)
            return np.bincount(space.pos, weights=weights * x[space.idx], minlength=space.n)
        key = (id(space), id(weights), id(mask))
        hit = self._space_ops.get(key)
        if hit is None or hit[0][0] is not space or hit[0][1] is not weights or hit[0][2] is not mask:
            hit = ((space, weights, mask), self._build_space_solve(space, weights, mask))
            self._space_ops[key] = hit
        db, P, PT, coarse, cin, win, pp, pw, pc = hit[1]
        r_ext = np.concatenate([r, np.zeros(1)])
        xs = r_ext[cin]
        xs *= win
        ys = db.apply(xs)
        out = None
        if self.n_primal:
            b_pi = np.bincount(pc, weights=r[pp] * pw, minlength=self.n_primal + 1)
            u_ext = self._coarse_step((db, P, PT, coarse), xs, ys, b_pi)
            out = np.bincount(pp, weights=u_ext[pc] * pw, minlength=space.n)
        ys *= win
        y = np.bincount(cin, weights=ys, minlength=space.n + 1)[:-1]      # slot space.n: outside
        return y if out is None else y + out

    def _build_space_solve(self, space, weights, mask):
        db, P, PT, coarse = self._interface_blocks(mask)
        look = np.full(self.sub.n_W, -1, dtype=np.int64)
        look[space.idx] = np.arange(space.idx.size)
        ent = look[db.flat]
        sel = np.flatnonzero(ent >= 0)
        cin = np.full(db.flat.size, space.n, dtype=np.int64)
        cin[sel] = space.pos[ent[sel]]
        win = np.zeros(db.flat.size)
        win[sel] = weights[ent[sel]]
        pe = look[np.flatnonzero(self.primal)]
        pw_ent = pe[pe >= 0]
        pp = space.pos[pw_ent]
        pw = weights[pw_ent]
        pc = self.coarse_of_W[space.idx[pw_ent]]
        # entries outside the space carry weight 0 and land in the extra slot space.n
        return db, P, PT, coarse, cin, win, pp, pw, pc

    def solve_interface(self, b: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """:meth:`solve` for a right-hand side supported on ``mask`` (zero on every other entry),
        returning the solution on ``mask`` only (zero elsewhere).

        ``mask`` (an interface: every interior entry of the subdomains is
        outside it) must be a persistent array, the cache key. Uses explicit
        dense blocks (A_rr^{-1})_{DD} = S_DD^{-1} on D = r & mask, formed on
        first use from the existing factorizations (no new factorization), so
        one application costs one GEMM per group of the interface size, where that
        pays off (:meth:`_explicit_interface`; otherwise :meth:`solve`).
        """
        if not self._explicit_interface(mask):
            return np.where(mask, self.solve(np.where(mask, b, 0.0)), 0.0)
        blocks = self._interface_blocks(mask)
        db = blocks[0]
        bs = b[db.flat]
        xs = db.apply(bs)
        x = np.zeros(self.sub.n_W)
        if self.n_primal:
            b_pi = np.bincount(self.coarse_of_W[self.primal], weights=b[self.primal], minlength=self.n_primal + 1)
            u_ext = self._coarse_step(blocks, bs, xs, b_pi)
            x[self.primal] = u_ext[self.coarse_of_W[self.primal]]
        x[db.flat] = xs
        return np.where(mask, x, 0.0)


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
