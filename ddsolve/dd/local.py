"""Batched subdomain solves with shared factorizations.

Subdomains are the unit of work. A :class:`BatchedSolver` solves
K^(i)_{JJ} x^(i) = b^(i) for *all* subdomains i at once, where J_i is a subset
of the local degrees of freedom (e.g. the interior nodes for Dirichlet solves,
or all but the primal nodes for FETI-DP). Since A^(i) = rho_i K_t (see
:mod:`ddsolve.scene.assembly`), subdomains with the same template t and the
same local index set J share one factorization of K_t[J, J]; each group is
solved as one multi-right-hand-side solve and scaled by 1/rho_i.
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


class _Factor:
    """Cholesky (dense) or LU (sparse) factorization of one SPD matrix."""

    def __init__(self, K: sp.spmatrix) -> None:
        self.n = K.shape[0]
        self._inv: np.ndarray | None = None
        if self.n <= DENSE_LIMIT:
            self.kind = "dense"
            self._f = la.cho_factor(K.toarray(), lower=False, check_finite=False)
        else:
            self.kind = "sparse"
            self._f = spla.splu(sp.csc_matrix(K), permc_spec="MMD_AT_PLUS_A",
                                options={"SymmetricMode": True})

    def solve(self, B: np.ndarray) -> np.ndarray:
        if self.kind == "dense":
            if B.ndim == 2 and B.shape[1] >= GEMM_MIN_COLUMNS:
                if self._inv is None:       # from the Cholesky factor, once (SPD, well conditioned blocks)
                    self._inv = la.cho_solve(self._f, np.eye(self.n), check_finite=False)
                return self._inv @ B
            return la.cho_solve(self._f, B, check_finite=False)
        return self._f.solve(np.asfortranarray(B))


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
        groups: dict[bytes, tuple[int, np.ndarray, list[int]]] = {}
        for s in range(layout.n_sub):
            lo, hi = layout.offsets[s], layout.offsets[s + 1]
            loc = layout.local_index[lo:hi][select[lo:hi]]
            if loc.size == 0:
                continue
            t = int(layout.template[s])
            key = t.to_bytes(8, "little") + loc.astype(np.int64).tobytes()
            if key not in groups:
                groups[key] = (t, loc, [])
            groups[key][2].append(s)
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
        log.debug("BatchedSolver: %d groups, %d new factorizations", len(self.groups), self.n_new_factorizations)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x = blockdiag(K^(i)_{JJ})^{-1} b, shape (n_W,) (zeros outside J)."""
        x = np.zeros(self.n_W)
        for g in self.groups:
            x[g.index] = g.factor.solve(b[g.index]) * g.inv_rho
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
