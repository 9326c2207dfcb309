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
diagonal average is. Every other interface entry (primal vertices, dual dofs
shared by more than two subdomains) keeps its diagonal weight delta.

With D = blockdiag_i(D_i) on the unassembled space W (the deluxe blocks on
the faces, delta elsewhere) the operators are

* BDDC (Section 2.7): R~_D = D^T R, so that M^{-1} = R^T D Ã^{-1} D^T R;
* FETI-DP (Section 2.6): B_D^T = (I - E_D) B^T (B B^T)^{-1}, which gives the
  identity P_D = B_D^T B = I - E_D of the theory; on a face (two copies per dof,
  one multiplier per dof) B B^T = 2 I. Multipliers of dofs shared by more than
  two subdomains keep the diagonal B_D rows.

Setup cost: the explicit local Schur complements (one local interior solve per
interface dof of every subdomain, batched, :meth:`DirichletSchur.explicit_blocks`)
and one stacked dense solve per face size. Application: one sparse product with
D (sum over faces of 2 m_F^2 entries).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

__all__ = ["DeluxeScaling", "deluxe_scaling"]


@dataclass
class DeluxeScaling:
    """The block-diagonal scaling D of the unassembled space W.

    Attributes
    ----------
    D : scipy.sparse.csr_matrix, shape (n_W, n_W)
        D_i^F on the entries of every face side, ``delta`` on the diagonal elsewhere.
    face_entries : ndarray of bool, shape (n_W,)
        The W entries scaled by a deluxe block.
    n_faces : int
        Number of faces (pairs of subdomains with a dual dof in common).
    largest_face : int
        Dofs of the largest face.
    """

    D: sp.csr_matrix
    face_entries: np.ndarray
    n_faces: int
    largest_face: int

    def jump(self, B: sp.csr_matrix, B_D: sp.csr_matrix, R: sp.csr_matrix) -> sp.csr_matrix:
        """The deluxe B_D (n_lambda, n_W) from the jump operator B and its diagonal version.

        ``R`` (n_W, n_g): the 0/1 scatter of assembled interface values to their copies.
        Rows whose two entries lie on a face: (1/2) B (I - E_D^T) with E_D = R R^T D; the
        other rows are those of ``B_D``.
        """
        B = sp.csr_matrix(B)
        copies = np.diff(B.indptr)
        on_face = np.zeros(B.shape[0], dtype=bool)
        if B.nnz:
            rows = np.repeat(np.arange(B.shape[0]), copies)
            hits = np.bincount(rows, weights=self.face_entries[B.indices].astype(float), minlength=B.shape[0])
            on_face = (copies == 2) & (hits == 2)
        sel = sp.diags(on_face.astype(float))
        Bf = sel @ B
        E_T = (self.D.T @ R) @ R.T                      # E_D^T = D^T R R^T
        deluxe_rows = 0.5 * (Bf - Bf @ E_T)
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

    entries = np.flatnonzero(dual & (a_off >= 0))
    node = sub.node_of_W[entries]
    order = np.lexsort((sub.sub_of_W[entries], node))
    entries, node = entries[order], node[order]
    starts = np.flatnonzero(np.r_[True, node[1:] != node[:-1]])
    count = np.diff(np.r_[starts, node.size])
    pairs = starts[count == 2]                          # dofs with exactly two copies
    first, second = entries[pairs], entries[pairs + 1]  # first: the lower subdomain
    key = sub.sub_of_W[first].astype(np.int64) * sub.n_sub + sub.sub_of_W[second]
    by_face = np.lexsort((sub.node_of_W[first], key))   # faces, dofs in node order
    first, second, key = first[by_face], second[by_face], key[by_face]
    face_start = np.flatnonzero(np.r_[key.size > 0, key[1:] != key[:-1]])   # no faces: none
    face_size = np.diff(np.r_[face_start, key.size])

    rows_i, cols_i, vals = [], [], []
    for m in np.unique(face_size):
        st = face_start[face_size == m]
        pos = st[:, None] + np.arange(m)                # (c, m) indices into first/second
        sides = []
        for side in (first[pos], second[pos]):
            r = row[side]
            base = a_off[side[:, 0]][:, None, None] + r[:, :, None] * size[side[:, 0]][:, None, None]
            sides.append(A_flat[base + r[:, None, :]] * scale[side[:, 0]][:, None, None])
        S_a, S_b = sides
        D_a = np.linalg.solve(S_a + S_b, S_a)           # (c, m, m)
        D_b = np.eye(m)[None] - D_a
        for side, D_s in ((first[pos], D_a), (second[pos], D_b)):
            rows_i.append(np.repeat(side, m, axis=1).ravel())
            cols_i.append(np.tile(side, (1, m)).ravel())
            vals.append(D_s.ravel())
    face_entries = np.zeros(n_W, dtype=bool)
    face_entries[first] = face_entries[second] = True
    rest = np.flatnonzero(~face_entries)
    rows_i.append(rest)
    cols_i.append(rest)
    vals.append(np.asarray(delta)[rest])
    D = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows_i), np.concatenate(cols_i))), shape=(n_W, n_W))
    log.debug("deluxe scaling: %d faces, largest %d dofs, %d entries", face_start.size,
              int(face_size.max(initial=0)), D.nnz)
    return DeluxeScaling(D=D, face_entries=face_entries, n_faces=int(face_start.size),
                         largest_face=int(face_size.max(initial=0)))
