"""Batched subdomain solves with shared factorizations.

Subdomains are the unit of work. A :class:`BatchedSolver` solves
K^(i)_{JJ} x^(i) = b^(i) for *all* subdomains i at once, where J_i is a subset
of the local degrees of freedom (e.g. the interior nodes for Dirichlet solves,
or all but the primal nodes for FETI-DP). Since A^(i) = rho_i K_t (see
:mod:`ddsolve.scene.assembly`), subdomains with the same template t and the
same local index set J share one factorization of K_t[J, J]; each group is
solved as one multi-right-hand-side solve and scaled by 1/rho_i.

Distinct subdomains (no template shared by two of them, as on any
unstructured mesh, or with ``Substructures(..., templates=False)``) are not
factored one by one: all their blocks K^(i)_{JJ} are put into one sparse
block-diagonal matrix with a single sparse factorization (scipy SuperLU,
symmetric mode, minimum degree on A^T + A), and :meth:`BatchedSolver.solve`
applies it with one call for all of them. Per-subdomain solves (used by the
operators to form explicit local blocks at setup) read the block's own rows
of the triangular factors (:class:`_BlockView`), whose cost is that of the
block, not of the whole matrix.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

log = logging.getLogger(__name__)

#: Local blocks up to this size are factored densely (Cholesky, BLAS-3 multi-RHS solves).
DENSE_LIMIT = 1200
#: Dense blocks applied to at least this many right-hand sides at once use the explicit
#: inverse (one GEMM) instead of two triangular solves: measured 2-4x faster for
#: 225-800 unknowns and >= 60 columns with one BLAS thread; fewer columns keep the
#: triangular solves, which read half the memory.
GEMM_MIN_COLUMNS = 48
#: Subdomains that share no factorization are factored together (one block-diagonal sparse
#: factorization) when at least this many subdomains have a template of their own, or when the
#: layout asks for it (``batch_local``, e.g. ``Substructures(..., templates=False)``); otherwise
#: (structured scenes) every distinct (template, index set) keeps its own factorization.
BATCH_MIN_SUBDOMAINS = 16


class _Factor:
    """Cholesky (dense) or LU (sparse) factorization of one SPD matrix.

    With :meth:`set_blocks` the matrix is declared block diagonal, and
    :meth:`solve_block` solves with one diagonal block only.
    """

    def __init__(self, K: sp.spmatrix) -> None:
        self.n = K.shape[0]
        self._inv: np.ndarray | None = None
        self._blocks: np.ndarray | None = None
        self._block_pos: tuple | None = None
        if self.n <= DENSE_LIMIT:
            self.kind = "dense"
            self._f = la.cho_factor(K.toarray(), lower=False, check_finite=False)
        else:
            self.kind = "sparse"
            # SPD: diagonal pivots only (DiagPivotThresh 0); threshold pivoting off the diagonal destroys
            # the symmetric ordering (measured on a P2 block of 14,224 dofs: 25x the fill, 30x the time)
            self._f = spla.splu(sp.csc_matrix(K), permc_spec="MMD_AT_PLUS_A",
                                options={"SymmetricMode": True, "DiagPivotThresh": 0.0})

    def solve(self, B: np.ndarray) -> np.ndarray:
        if self.kind == "dense":
            if B.ndim == 2 and B.shape[1] >= GEMM_MIN_COLUMNS:
                if self._inv is None:       # from the Cholesky factor, once (SPD, well conditioned blocks)
                    self._inv = la.cho_solve(self._f, np.eye(self.n), check_finite=False)
                return self._inv @ B
            return la.cho_solve(self._f, B, check_finite=False)
        return self._f.solve(np.asfortranarray(B))

    def set_blocks(self, offsets: np.ndarray) -> None:
        """Declare the factored matrix block diagonal with blocks offsets[b]:offsets[b+1]."""
        self._blocks = np.asarray(offsets, dtype=np.int64)

    def _positions(self) -> tuple:
        """(block of each pivot position, positions sorted by block, their start per block, local index)."""
        if self._block_pos is None:
            perm_c = self._f.perm_c                     # column i of K is column perm_c[i] of the factors
            block_of_col = np.searchsorted(self._blocks, np.arange(self.n), side="right") - 1
            block_of_pos = np.empty(self.n, dtype=np.int64)
            block_of_pos[perm_c] = block_of_col
            order = np.argsort(block_of_pos, kind="stable")     # positions of block b, increasing
            starts = np.searchsorted(block_of_pos[order], np.arange(self._blocks.size))
            local = np.empty(self.n, dtype=np.int64)
            local[order] = np.arange(self.n) - starts[block_of_pos[order]]
            self._block_pos = (order, starts, local, self._f.L.tocsc(), self._f.U.tocsc())
        return self._block_pos

    def solve_block(self, b: int, B: np.ndarray) -> np.ndarray:
        """K_bb^{-1} B for diagonal block b only, B of shape (n_b,) or (n_b, k).

        Sparse factors: P_r K P_c = L U (SuperLU: row i of K is row perm_r[i]
        of P_r K, column i of K is column perm_c[i] of K P_c), with L, U block
        diagonal up to the permutation (no fill between disconnected blocks,
        pivots stay in their block), so x = P_c U_bb^{-1} L_bb^{-1} P_r B on
        the positions of block b; cost O(nnz(L_bb + U_bb) k).
        """
        lo, hi = int(self._blocks[b]), int(self._blocks[b + 1])
        if self.kind == "dense":
            if self._inv is None:
                self._inv = la.cho_solve(self._f, np.eye(self.n), check_finite=False)
            return self._inv[lo:hi, lo:hi] @ B
        order, starts, local, L, U = self._positions()
        pos = order[starts[b]:starts[b] + (hi - lo)]             # pivot positions of block b
        Lb = L[:, pos]
        Lb = sp.csc_matrix((Lb.data, local[Lb.indices], Lb.indptr), shape=(hi - lo, hi - lo))
        Ub = U[:, pos]
        Ub = sp.csc_matrix((Ub.data, local[Ub.indices], Ub.indptr), shape=(hi - lo, hi - lo))
        perm_r, perm_c = self._f.perm_r, self._f.perm_c
        rhs = np.zeros((hi - lo,) + B.shape[1:])
        rhs[local[perm_r[lo:hi]]] = B                          # row i of K goes to position perm_r[i]
        y = spla.spsolve_triangular(Lb.tocsr(), rhs, lower=True, unit_diagonal=True)
        z = spla.spsolve_triangular(Ub.tocsr(), y, lower=False)
        return z[local[perm_c[lo:hi]]]                         # x_i = z at the position of column i


class _BlockView:
    """One diagonal block of a block-diagonal :class:`_Factor`, with the ``solve`` of a factor."""

    def __init__(self, factor: _Factor, block: int, n: int) -> None:
        self.factor, self.block, self.n = factor, block, n
        self.kind = "block"

    def solve(self, B: np.ndarray) -> np.ndarray:
        return self.factor.solve_block(self.block, np.asarray(B, dtype=float))


@dataclass
class _Group:
    factor: _Factor
    index: np.ndarray       # (n_J, n_members) positions in the W vector
    inv_rho: np.ndarray     # (n_members,)
    loc: np.ndarray         # (n_J,) template-local indices J
    members: np.ndarray     # (n_members,) subdomains


class BatchedSolver:
    """Solve K^(i)_{JJ} x = b on all subdomains at once.

    Parameters
    ----------
    layout : ddsolve.dd.substructure.Substructures
        Subdomain layout of the unassembled space W.
    select : ndarray of bool, shape (n_W,)
        Entries of W that belong to the index sets J_i.
    cache : dict, optional
        Factorization cache shared between solvers of one solve, keyed by
        (template, local index set); a hit is not refactored.

    Notes
    -----
    ``solve(b)`` reads b on the selected entries, returns x with zeros
    elsewhere. Cost per call: one multi-RHS triangular solve per group.
    """

    def __init__(self, layout: Any, select: np.ndarray, cache: dict | None = None) -> None:
        self.n_W = layout.n_W
        self.select = select
        cache = {} if cache is None else cache
        sub_of_W = layout.sub_of_W
        count = np.bincount(sub_of_W[select], minlength=layout.n_sub)
        template = np.asarray(layout.template)
        n_members = np.bincount(template, minlength=int(template.max()) + 1 if template.size else 0)
        shared = (n_members[template] > 1) & (count > 0)        # candidates for a shared factorization
        groups = self._group(layout, select, np.flatnonzero(shared))
        alone = [ms[0] for _, _, ms in groups.values() if len(ms) == 1]
        single = ~shared & (count > 0)
        single[np.asarray(alone, dtype=np.int64)] = True
        batch = getattr(layout, "batch_local", None)
        if batch is None:               # many subdomains with a template of their own (unstructured meshes)
            batch = int(np.count_nonzero(~shared & (count > 0))) >= BATCH_MIN_SUBDOMAINS
        if batch:        # the subdomains of a shared template and local set keep one shared factorization
            groups = {k: g for k, g in groups.items() if len(g[2]) > 1}
        else:            # few distinct subdomains: one factorization each (groups in subdomain order)
            groups = self._group(layout, select, np.flatnonzero(count > 0))
            single[:] = False
        self.groups: list[_Group] = []
        self.n_new_factorizations = 0
        for key, (t, loc, members) in groups.items():
            if key not in cache:
                K = layout.stiffness[t][loc][:, loc]
                cache[key] = _Factor(K)
                self.n_new_factorizations += 1
            members_arr = np.asarray(members)
            # positions: W offset of each member + position of loc within its free local dofs
            index = np.stack([layout.position(s, loc) for s in members_arr], axis=1)
            self.groups.append(_Group(cache[key], index, 1.0 / layout.rho[members_arr], loc, members_arr))
        self._batch: tuple | None = None
        if single.any():
            self._build_batch(layout, select, single, count, cache)
        log.debug("BatchedSolver: %d groups (%d batched), %d new factorizations", len(self.groups),
                  int(single.sum()), self.n_new_factorizations)

    @staticmethod
    def _group(layout: Any, select: np.ndarray, subs: np.ndarray) -> dict:
        """Subdomains ``subs`` grouped by (template, local index set J): key -> (t, loc, members)."""
        groups: dict[bytes, tuple[int, np.ndarray, list[int]]] = {}
        for s in subs:
            lo, hi = layout.offsets[s], layout.offsets[s + 1]
            loc = layout.local_index[lo:hi][select[lo:hi]]
            t = int(layout.template[s])
            key = t.to_bytes(8, "little") + loc.astype(np.int64).tobytes()
            if key not in groups:
                groups[key] = (t, loc, [])
            groups[key][2].append(int(s))
        return groups

    def _build_batch(self, layout: Any, select: np.ndarray, single: np.ndarray, count: np.ndarray,
                     cache: dict) -> None:
        """One factorization of blockdiag(K^(i)_{JJ}) over the subdomains ``single`` (unit coefficient)."""
        import hashlib

        entries = np.flatnonzero(select & single[layout.sub_of_W])           # W order: block by block
        members = np.flatnonzero(single)
        sizes = count[members]
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        key = b"batch" + hashlib.sha1(entries.astype(np.int64).tobytes()).digest()
        if key not in cache:
            inv_rho_e = 1.0 / layout.rho[layout.sub_of_W[entries]]
            K = layout.K_W[entries][:, entries]
            K = sp.csc_matrix(sp.diags(inv_rho_e) @ K)                   # rho_i K_t -> K_t, block by block
            factor = _Factor(K)
            factor.set_blocks(offsets)
            cache[key] = factor
            self.n_new_factorizations += 1
        factor = cache[key]
        inv_rho = 1.0 / layout.rho[members]
        self._batch = (factor, entries, np.repeat(inv_rho, sizes))
        loc_all = layout.local_index[entries]
        for b, s in enumerate(members):
            lo, hi = offsets[b], offsets[b + 1]
            view = _BlockView(factor, b, int(hi - lo))
            # the operators look factorizations up by (template, local set J) when forming explicit blocks
            cache.setdefault(int(layout.template[s]).to_bytes(8, "little")
                             + loc_all[lo:hi].astype(np.int64).tobytes(), view)
            self.groups.append(_Group(view, entries[lo:hi, None], inv_rho[b:b + 1], loc_all[lo:hi],
                                      members[b:b + 1]))

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x = blockdiag(K^(i)_{JJ})^{-1} b, shape (n_W,) (zeros outside J).

        One multi-RHS solve per shared factorization and one call for all
        batched subdomains; ``b`` may have shape (n_W, k) (k right-hand sides).
        """
        x = np.zeros(b.shape)
        for g in self.groups:
            if isinstance(g.factor, _BlockView):
                continue
            if b.ndim == 1:
                x[g.index] = g.factor.solve(b[g.index]) * g.inv_rho
            else:
                n, m = g.index.shape
                y = g.factor.solve(b[g.index].reshape(n, -1)).reshape(n, m, -1)
                x[g.index] = y * g.inv_rho[None, :, None]
        if self._batch is not None:
            factor, entries, inv_rho = self._batch
            y = factor.solve(b[entries])
            x[entries] = y * (inv_rho if b.ndim == 1 else inv_rho[:, None])
        return x


class DenseBlocks:
    """Apply dense local matrices to groups of subdomain vectors: y_i = s_i A_t x_i.

    Parameters
    ----------
    blocks : sequence of (A, index, scale)
        ``A`` (n, n) dense, shared by the members of the group; ``index``
        (n, n_members) W positions of the members' entries; ``scale``
        (n_members,) factor of each member (rho_i or 1/rho_i).

    Attributes
    ----------
    flat : ndarray of int
        All W positions, group by group (C order of each ``index``); every
        position occurs once if the groups do not overlap.

    Notes
    -----
    :meth:`apply` works on the compact vector ``x[flat]``: one gather before,
    one scatter after, and one GEMM per group in between, with no per-group
    fancy-index copies.
    """

    def __init__(self, blocks) -> None:
        self.parts: list[tuple[np.ndarray, int, int, int, np.ndarray]] = []
        flats, off = [], 0
        for A, index, scale in blocks:
            n, n_m = index.shape
            self.parts.append((np.ascontiguousarray(A, dtype=float), off, n, n_m,
                               np.asarray(scale, dtype=float)))
            flats.append(np.asarray(index, dtype=np.int64).ravel())
            off += n * n_m
        self.flat = np.concatenate(flats) if flats else np.zeros(0, dtype=np.int64)
        self.size = off

    def apply(self, xs: np.ndarray) -> np.ndarray:
        """ys = blockdiag(s_i A_t) xs for a compact vector xs = x[flat], shape (size,)."""
        ys = np.empty(self.size)
        for A, off, n, n_m, scale in self.parts:
            out = ys[off:off + n * n_m].reshape(n, n_m)
            np.matmul(A, xs[off:off + n * n_m].reshape(n, n_m), out=out)
            out *= scale
        return ys
