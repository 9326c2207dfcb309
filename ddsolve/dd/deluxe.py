"""Deluxe scaling for BDDC and FETI-DP (Dohrmann and Widlund; not in the thesis).

The thesis scales the interface by the diagonal delta-dagger weights of
Section 2.3 (rho-scaling: one coefficient per subdomain). When a coefficient
jumps *inside* subdomains, as when METIS parts cut across materials, no
diagonal weight is robust. Deluxe scaling replaces the weights of every face F
shared by two subdomains i and j (in 2D an interface edge, all of its dual
dofs) by the dense matrices

    D_i^F = (S_i^F + S_j^F)^{-1} S_i^F,    D_j^F = (S_i^F + S_j^F)^{-1} S_j^F,

where S_i^F is the principal minor on F of the local Schur complement S_i
(interior eliminated). D_i^F + D_j^F = I, so the weighted average
E_D w = D_i^F w_i + D_j^F w_j is a projection onto continuous values, as the
diagonal average is. The same holds for any *glob* G, the dual dofs shared by
the same set N_G of m >= 2 subdomains: D_i^G = (sum_{j in N_G} S_j^G)^{-1} S_i^G.
With m = 2 these are the faces; m >= 3 occurs for the dual dofs of the 3D
subdomain edges under edge averages (``primal="vertices+edges"``, where they
are the zero-mean parts of the change of basis (2.22)). Every other interface
entry keeps its diagonal weight delta.

With D = blockdiag_i(D_i) on the unassembled space W (the deluxe blocks on
the faces, delta elsewhere) the operators are

* BDDC (Section 2.7): R~_D = D^T R, so that M^{-1} = R^T D Ã^{-1} D^T R;
* FETI-DP (Section 2.6): B_D^T = (I - E_D) B^T / m on the rows of a glob of m
  copies, which gives the identity P_D = B_D^T B = I - E_D of the theory: the
  multipliers are fully redundant (one per pair of copies), so on a dof
  B^T B = m I - 1 1^T, and (I - E_D) 1 = 0. On a face (m = 2) this is
  (I - E_D) B^T (B B^T)^{-1} with B B^T = 2 I. The other rows keep the diagonal B_D.

Setup cost: the explicit local Schur complements (one local interior solve per
interface dof of every subdomain, batched, :meth:`DirichletSchur.explicit_blocks`)
and one stacked dense solve per glob shape. Application: one sparse product with
D (sum over globs of m k_G^2 entries, k_G dofs).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..scene.scene import unique_row_labels

log = logging.getLogger(__name__)

__all__ = ["DeluxeScaling", "deluxe_scaling"]


@dataclass
class DeluxeScaling:
    """The block-diagonal scaling D of the unassembled space W.

    Attributes
    ----------
    D : scipy.sparse.csr_matrix, shape (n_W, n_W)
        D_i^G on the entries of every glob side, ``delta`` on the diagonal elsewhere.
    face_entries : ndarray of bool, shape (n_W,)
        The W entries scaled by a deluxe block.
    n_faces : int
        Number of globs: faces (pairs of subdomains with a dual dof in common) and, in 3D with
        edge averages, the dual edge globs (three or more subdomains).
    largest_face : int
        Dofs of the largest glob.
    copies : ndarray of int, shape (n_W,)
        m, the number of copies of the entry's dof, on the deluxe entries (0 elsewhere).
    """

    D: sp.csr_matrix
    face_entries: np.ndarray
    n_faces: int
    largest_face: int
    copies: np.ndarray

    def jump(self, B: sp.csr_matrix, B_D: sp.csr_matrix, R: sp.csr_matrix) -> sp.csr_matrix:
        """The deluxe B_D (n_lambda, n_W) from the jump operator B and its diagonal version.

        ``R`` (n_W, n_g): the 0/1 scatter of assembled interface values to their copies.
        Rows whose two entries lie on a glob of m copies: (1/m) B (I - E_D^T) with
        E_D = R R^T D; the other rows are those of ``B_D``.
        """
        B = sp.csr_matrix(B)
        entries = np.diff(B.indptr)
        on_face = np.zeros(B.shape[0], dtype=bool)
        m = np.ones(B.shape[0])
        if B.nnz:
            rows = np.repeat(np.arange(B.shape[0]), entries)
            hits = np.bincount(rows, weights=self.face_entries[B.indices].astype(float), minlength=B.shape[0])
            on_face = (entries == 2) & (hits == 2)
            m[on_face] = self.copies[B.indices[B.indptr[:-1][on_face]]]     # copies of the row's dof
        Bf = sp.diags(on_face / m) @ B                  # 1/2 on a face: exact, as (1/2) (B - B E_D^T)
        E_T = (self.D.T @ R) @ R.T                      # E_D^T = D^T R R^T
        deluxe_rows = Bf - Bf @ E_T
        return sp.csr_matrix(deluxe_rows + sp.diags((~on_face).astype(float)) @ sp.csr_matrix(B_D))


def deluxe_scaling(sub, blocks, dual: np.ndarray, delta: np.ndarray) -> DeluxeScaling:
    """Deluxe scaling of the dual interface entries ``dual`` from explicit local Schur complements.

    Parameters
    ----------
    sub : Substructures
        Layout (``sub_of_W``, ``node_of_W``, ``n_sub``).
    blocks : ddsolve.dd.local.DenseBlocks
        The local Schur complements S_i (rows: W positions of the interface of
        subdomain i), e.g. :meth:`~ddsolve.dd.operators.DirichletSchur.explicit_blocks`.
    dual : ndarray of bool, shape (n_W,)
        Interface entries that are not primal.
    delta : ndarray, shape (n_W,)
        Diagonal weights kept off the faces.

    Returns
    -------
    DeluxeScaling
    """
    n_W = sub.n_W
    # where every W position sits in the blocks: (flat A offset, row, block size, member scale);
    # blocks.flat holds group k's positions as an (n_k, members_k) C-order array from offset o_k
    n = np.array([p[2] for p in blocks.parts], dtype=np.int64)
    n_m = np.array([p[3] for p in blocks.parts], dtype=np.int64)
    group = np.repeat(np.arange(n.size), n * n_m)                          # group of each flat entry
    local = np.arange(blocks.size) - np.repeat(np.array([p[1] for p in blocks.parts], dtype=np.int64), n * n_m)
    member = local % n_m[group]
    a_off = np.full(n_W, -1, dtype=np.int64)
    row = np.zeros(n_W, dtype=np.int64)
    size = np.zeros(n_W, dtype=np.int64)
    scale = np.zeros(n_W)
    a_off[blocks.flat] = np.concatenate([[0], np.cumsum(n * n)])[group]
    row[blocks.flat] = local // n_m[group]
    size[blocks.flat] = n[group]
    scale[blocks.flat] = np.concatenate([p[4] for p in blocks.parts] or [np.zeros(0)])[
        np.concatenate([[0], np.cumsum(n_m)])[group] + member]
    A_flat = np.concatenate([p[0].ravel() for p in blocks.parts] or [np.zeros(0)])

    def minors(side: np.ndarray) -> np.ndarray:
        """S_i^G of the (c, k) W entries ``side`` (each row one subdomain's copies of a glob), (c, k, k)."""
        r = row[side]
        base = a_off[side[:, 0]][:, None, None] + r[:, :, None] * size[side[:, 0]][:, None, None]
        return A_flat[base + r[:, None, :]] * scale[side[:, 0]][:, None, None]

    entries = np.flatnonzero(dual & (a_off >= 0))
    node = sub.node_of_W[entries]
    order = np.lexsort((sub.sub_of_W[entries], node))
    entries, node = entries[order], node[order]
    starts = np.flatnonzero(np.r_[node.size > 0, node[1:] != node[:-1]])
    count = np.diff(np.r_[starts, node.size])
    face_entries = np.zeros(n_W, dtype=bool)
    copies = np.zeros(n_W, dtype=np.int64)
    rows_i, cols_i, vals = [], [], []
    n_globs, largest = 0, 0
    for m in np.unique(count[count >= 2]):
        st = starts[count == m]                             # dofs with m copies: their first entry
        subs = sub.sub_of_W[entries[st[:, None] + np.arange(m)]]     # (n, m), sorted rows
        glob = unique_row_labels(subs)
        by_glob = np.lexsort((node[st], glob))             # globs by subdomain set, dofs in node order
        st, glob = st[by_glob], glob[by_glob]
        glob_start = np.flatnonzero(np.r_[True, glob[1:] != glob[:-1]])
        glob_size = np.diff(np.r_[glob_start, glob.size])
        n_globs += glob_start.size
        largest = max(largest, int(glob_size.max()))
        for k in np.unique(glob_size):
            pos = st[glob_start[glob_size == k][:, None] + np.arange(k)]     # (c, k) first entries
            sides = [entries[pos + j] for j in range(m)]    # copy j of every dof: subdomain N_G[j]
            S = [minors(side) for side in sides]
            total = S[0] + S[1]
            for S_j in S[2:]:
                total = total + S_j
            D = [np.linalg.solve(total, S_j) for S_j in S[:-1]]
            last = np.eye(k)[None] - D[0]                   # sum_j D_j = I
            for D_j in D[1:]:
                last = last - D_j
            for side, D_s in zip(sides, D + [last]):
                rows_i.append(np.repeat(side, k, axis=1).ravel())
                cols_i.append(np.tile(side, (1, k)).ravel())
                vals.append(D_s.ravel())
                face_entries[side] = True
                copies[side] = m
    rest = np.flatnonzero(~face_entries)
    rows_i.append(rest)
    cols_i.append(rest)
    vals.append(np.asarray(delta)[rest])
    D = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows_i), np.concatenate(cols_i))), shape=(n_W, n_W))
    log.debug("deluxe scaling: %d globs, largest %d dofs, %d entries", n_globs, largest, D.nnz)
    return DeluxeScaling(D=D, face_entries=face_entries, n_faces=n_globs, largest_face=largest, copies=copies)
