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
block-diagonal matrix with a single sparse factorization, and
:meth:`BatchedSolver.solve` applies it with one call for all of them. The
batched factorization uses MKL PARDISO (:mod:`ddsolve.dd.pardiso`: SPD
Cholesky, one thread, the elimination order of one METIS nested dissection per
subdomain shared by all index sets, :data:`BATCH_ORDERING`) when the ``mkl``
wheel loads, else scipy SuperLU (symmetric mode, diagonal pivots, minimum
degree on A^T + A), the backend of every other sparse local factorization;
:data:`SPARSE_BACKEND` selects it. Setup solves of many blocks share multi-column solves
(:func:`solve_many`); a solve with one block alone (:class:`_BlockView`) reads
the block's own rows of SuperLU's triangular factors, whose cost is that of the
block, not of the whole matrix (PARDISO: one solve of the whole matrix).
"""
from __future__ import annotations

import itertools
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
#: Backend of the batched block-diagonal factorization: ``"auto"`` (MKL PARDISO when the ``mkl``
#: wheel loads, else SuperLU), ``"pardiso"`` (error without MKL) or ``"superlu"`` (the literal
#: variant). Measured on the block-diagonal K_rr of 1,094,241 dofs / 1,024 METIS subdomains
#: (1,160,813 unknowns, one thread, CPU seconds): SuperLU factor 5.8 s, solve 0.17 s; PARDISO
#: (its METIS ordering) 4.0 s and 0.07-0.13 s. FETI-DP there, CPU in one process: SuperLU
#: 21.8 s, PARDISO 14.3 s, PARDISO with :data:`BATCH_ORDERING` "subdomain" 11.3 s
#: (docs/performance.md).
SPARSE_BACKEND = "auto"
#: A SuperLU solve with many right-hand sides runs on column blocks of about this many
#: entries (n x columns; 512 KB of float64, so a block stays in a core's L2 cache beside the
#: factors). Measured on one template of a structured scene (4,225 unknowns, 256 columns,
#: one thread): 32.6 ms in one call, 20.4 ms in blocks of 16 columns; two processes at once,
#: 50 ms each in one call and 21 ms each in blocks (the one call is bound by the shared
#: cache and memory, the blocks are not). Each column's result is unchanged.
SUPERLU_BLOCK_ENTRIES = 65536


#: Ordering of the batched PARDISO factorizations: ``"subdomain"`` (one METIS nested dissection of
#: each subdomain's matrix, computed once per cache and restricted to every index set J, so that
#: K_rr, K_II and K^+ share it) or ``"pardiso"`` (PARDISO's own ordering of each whole matrix).
BATCH_ORDERING = "subdomain"


def _subdomain_ordering(layout: Any, cache: dict) -> np.ndarray:
    """Nested-dissection order of the W entries, subdomain by subdomain (cached).

    With ``layout.ordering_anchors`` (an (n_W, m) array of W entries of the same
    subdomain, -1 padded; see :func:`_anchored_order`), the nested dissection runs
    on the graph of the entries that anchor to themselves only (e.g. the mesh
    vertices of a higher-order space), and every other entry is eliminated just
    before the first eliminated of its anchors.

    Returns
    -------
    ndarray of int, shape (n_W,)
        W positions in elimination order: those of subdomain 0 first (METIS
        ``NodeND`` of the graph of K^(0)), then subdomain 1, ...
    """
    import hashlib

    offsets = np.asarray(layout.offsets, dtype=np.int64)
    anchors = getattr(layout, "ordering_anchors", None)
    key = (b"subdomain-nd-ordering" + (b"anchored" if anchors is not None else b"")
           + hashlib.sha1(offsets.tobytes()).digest())                               # of this layout
    if key not in cache:
        G = sp.csr_matrix(layout.K_W)
        if anchors is None:
            cache[key] = _nested_dissection(G, offsets)
        else:
            cache[key] = _anchored_order(G, offsets, np.asarray(anchors, dtype=np.int64))
    return cache[key]


def _nested_dissection(G: sp.csr_matrix, offsets: np.ndarray) -> np.ndarray:
    """METIS ``NodeND`` of each diagonal block G[lo:hi, lo:hi] (blocks given by ``offsets``), shape (n,)."""
    import pymetis

    rows = np.repeat(np.arange(G.shape[0]), np.diff(G.indptr))
    off = G.indices != rows                                   # the graph: no self loops
    indptr = np.r_[0, np.cumsum(np.bincount(rows[off], minlength=G.shape[0]))]
    indices = G.indices[off].astype(np.int64)
    order = np.arange(G.shape[0], dtype=np.int64)
    for lo, hi in itertools.pairwise(offsets):              # setup: one METIS call per subdomain block
        a, b = indptr[lo], indptr[hi]
        if hi - lo > 2 and b > a:
            perm, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(indptr[lo:hi + 1] - a, indices[a:b] - lo))
            order[lo:hi] = lo + np.asarray(perm, dtype=np.int64)
    return order


def _anchored_order(G: sp.csr_matrix, offsets: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Nested dissection of the self-anchored entries; every other entry just before its first anchor.

    For a higher-order space the anchors of an edge (face) dof are the vertices of its
    mesh edge (face). In a nested dissection of the vertex graph, the other vertices of
    the elements around an edge lie in the subtree of the edge's first eliminated
    vertex or in the separators above it, so eliminating the edge dof just before that
    vertex keeps the dissection's structure, at the cost of one METIS call on
    1 / (number of dofs per vertex) of the graph. Any order gives the same factor up to
    rounding; only the fill depends on it.

    Parameters
    ----------
    G : csr_matrix, shape (n, n)
        Block diagonal (one block per subdomain).
    offsets : ndarray of int, shape (n_sub + 1,)
    anchors : ndarray of int, shape (n, m)
        Entries of the same block, -1 padded. Entry w anchors to itself when
        ``anchors[w, 0] == w`` or when it has no anchor.

    Returns
    -------
    ndarray of int, shape (n,)
        Entries in elimination order, block after block.
    """
    n = G.shape[0]
    own = (anchors[:, 0] == np.arange(n)) | (anchors.max(axis=1) < 0)
    selfs = np.flatnonzero(own)
    block = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))
    counts = np.bincount(block[own], minlength=offsets.size - 1)
    sub_offsets = np.concatenate([[0], np.cumsum(counts)])
    vertex_order = selfs[_nested_dissection(G[selfs][:, selfs].tocsr(), sub_offsets)]
    position = np.full(n, n, dtype=np.int64)
    position[vertex_order] = np.arange(vertex_order.size)
    padded = np.concatenate([position, [n]])                # anchor -1 reads position n (never first)
    first = padded[anchors].min(axis=1)
    key = np.where(own, 2 * position + 1, 2 * first)      # an anchored entry goes just before its anchor
    return np.argsort(key, kind="stable")


def _restricted_order(order_W: np.ndarray, entries: np.ndarray, n_W: int) -> np.ndarray:
    """The order of ``order_W`` restricted to ``entries``, as indices into ``entries``."""
    position = np.full(n_W, -1, dtype=np.int64)
    position[entries] = np.arange(entries.size)
    kept = position[order_W]
    return kept[kept >= 0]


def _sparse_backend(K: sp.spmatrix) -> str:
    """The backend of one batched factorization: "pardiso" or "superlu" (:data:`SPARSE_BACKEND`)."""
    from . import pardiso

    if SPARSE_BACKEND not in ("auto", "pardiso", "superlu"):
        raise ValueError(f"SPARSE_BACKEND must be 'auto', 'pardiso' or 'superlu', got {SPARSE_BACKEND!r}")
    if SPARSE_BACKEND == "superlu":
        return "superlu"
    if pardiso.available() and K.nnz <= pardiso.MAX_NNZ:
        return "pardiso"
    if SPARSE_BACKEND == "pardiso":
        raise ImportError("SPARSE_BACKEND = 'pardiso' needs Intel MKL (pip install mkl) and fewer than 2^31 "
                          "stored entries")
    return "superlu"


def _blocked_solve(factor: Any, B: np.ndarray) -> np.ndarray:
    """factor.solve(B) (SuperLU) on column blocks of :data:`SUPERLU_BLOCK_ENTRIES` entries.

    Parameters
    ----------
    factor : scipy.sparse.linalg.SuperLU
        The factors of an (n, n) matrix.
    B : ndarray, shape (n,) or (n, k), Fortran order
        Right-hand sides.

    Returns
    -------
    ndarray, shape of B
        The solutions, column by column those of one call on all of B.
    """
    columns = max(8, SUPERLU_BLOCK_ENTRIES // max(B.shape[0], 1))
    if B.ndim == 1 or B.shape[1] <= columns:
        return factor.solve(B)
    X = np.empty_like(B, order="F")
    for start in range(0, B.shape[1], columns):
        X[:, start:start + columns] = factor.solve(B[:, start:start + columns])
    return X


class _Factor:
    """Cholesky (dense) or LU (sparse) factorization of one SPD matrix.

    With :meth:`set_blocks` the matrix is declared block diagonal, and
    :meth:`solve_block` solves with one diagonal block only.

    Parameters
    ----------
    K : sparse matrix, shape (n, n)
        Symmetric positive definite.
    """

    #: K is the block-diagonal matrix of many subdomains (:class:`_BatchedFactor`): a sparse K
    #: is factored by the backend :data:`SPARSE_BACKEND` chooses; else SuperLU.
    batched = False
    #: A fill-reducing ordering for the batched backend (None: the backend's own).
    order: np.ndarray | None = None

    def __init__(self, K: sp.spmatrix) -> None:
        self.n = K.shape[0]
        self._inv: np.ndarray | None = None
        self._blocks: np.ndarray | None = None
        self._block_pos: tuple | None = None
        self.backend = "dense"
        if self.n <= DENSE_LIMIT:
            self.kind = "dense"
            self._f = la.cho_factor(K.toarray(), lower=False, check_finite=False)
        elif self.batched and _sparse_backend(K) == "pardiso":
            from .pardiso import PardisoCholesky

            self.kind, self.backend = "sparse", "pardiso"
            self._f = PardisoCholesky(K, order=self.order)
        else:
            self.kind, self.backend = "sparse", "superlu"
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
        if self.backend == "pardiso":
            return self._f.solve(B)
        return _blocked_solve(self._f, np.asfortranarray(B))

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
        if self.backend == "pardiso":              # no access to the factors: one solve of the whole matrix
            rhs = np.zeros((self.n,) + B.shape[1:])
            rhs[lo:hi] = B
            return self._f.solve(rhs)[lo:hi]
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


class _BatchedFactor(_Factor):
    """The factorization of a block-diagonal matrix of many subdomains (backend :data:`SPARSE_BACKEND`).

    ``order`` (optional, shape (n,)): the fill-reducing ordering handed to PARDISO.
    """

    batched = True

    def __init__(self, K: sp.spmatrix, order: np.ndarray | None = None) -> None:
        self.order = order
        super().__init__(K)


#: Columns per multi-right-hand-side solve of :func:`solve_many` (bounds its work array to
#: n x SOLVE_MANY_COLUMNS floats of the batched factorization) ...
SOLVE_MANY_COLUMNS = 32
#: ... and at most this many bytes per n x columns array (the solve makes a few of them: at
#: 132k unknowns 32 columns made a transient of 155 MB, 15 columns 77 MB; large factorizations take fewer).
SOLVE_MANY_BYTES = 16 * 2**20


def solve_chunk(n: int) -> int:
    """Columns per multi-right-hand-side solve of an n-unknown factorization (:data:`SOLVE_MANY_COLUMNS`,
    :data:`SOLVE_MANY_BYTES`)."""
    return max(1, min(SOLVE_MANY_COLUMNS, SOLVE_MANY_BYTES // (8 * max(n, 1))))


def solve_many(tasks: list[tuple]) -> list[np.ndarray]:
    """X_k = (K_k^{-1} B_k)[rows_k] for many (factor, B_k[, rows_k]), batched blocks sharing solves.

    Parameters
    ----------
    tasks : list of (factor, B) or (factor, B, rows)
        ``factor`` a :class:`_Factor` or a :class:`_BlockView`; ``B`` of shape
        (n_k, m_k), dense or scipy sparse; ``rows`` (optional) the rows of the
        solution to keep (all when None).

    Returns
    -------
    list of ndarray
        X_k of shape (len(rows_k), m_k), in the order of ``tasks``.

    Notes
    -----
    Blocks of one block-diagonal factorization K = diag(K_b) do not couple, so
    the right-hand sides of different blocks share columns: column c of one
    (n, m) right-hand side holds column c of every B_b on the rows of its
    block b, and one solve with K gives column c of every K_b^{-1} B_b. All
    setup solves of the batched subdomains (Psi, explicit Schur complements
    and interface blocks) thus cost max_b m_b columns of one sparse solve, in
    chunks of :data:`SOLVE_MANY_COLUMNS`, instead of one Python-level pair of
    triangular solves per subdomain.
    """
    def dense(B):
        return B.toarray() if sp.issparse(B) else np.asarray(B, dtype=float)

    out: list[np.ndarray | None] = [None] * len(tasks)
    batched: dict[int, list[int]] = {}
    for k, task in enumerate(tasks):
        factor, B = task[0], task[1]
        rows = task[2] if len(task) > 2 else None
        if isinstance(factor, _BlockView) and factor.factor.kind == "sparse":
            batched.setdefault(id(factor.factor), []).append(k)
        else:
            X = factor.solve(dense(B))
            out[k] = X if rows is None else X[rows]
    for ks in batched.values():
        whole = tasks[ks[0]][0].factor
        offsets = whole._blocks
        width = max(tasks[k][1].shape[1] for k in ks)
        chunk = solve_chunk(whole.n)
        for c0 in range(0, width, chunk):
            c1 = min(c0 + chunk, width)
            rhs = np.zeros((whole.n, c1 - c0), order="F")
            live = []
            for k in ks:
                view, B = tasks[k][0], tasks[k][1]
                m = B.shape[1]
                if c0 >= m:
                    continue
                lo, hi = int(offsets[view.block]), int(offsets[view.block + 1])
                rhs[lo:hi, :min(c1, m) - c0] = dense(B[:, c0:min(c1, m)])
                live.append(k)
            X = whole.solve(rhs)
            for k in live:
                view, B = tasks[k][0], tasks[k][1]
                rows = tasks[k][2] if len(tasks[k]) > 2 else None
                lo, hi = int(offsets[view.block]), int(offsets[view.block + 1])
                m = B.shape[1]
                Xk = X[lo:hi, :min(c1, m) - c0]
                if rows is not None:
                    Xk = Xk[rows]
                if out[k] is None:
                    out[k] = np.empty((Xk.shape[0], m))
                out[k][:, c0:min(c1, m)] = Xk
    for k, task in enumerate(tasks):
        if out[k] is None:                       # no columns
            n = task[1].shape[0] if len(task) < 3 or task[2] is None else len(task[2])
            out[k] = np.zeros((n, task[1].shape[1]))
    return out  # type: ignore[return-value]


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
            K = sp.csr_matrix(layout.K_W[entries][:, entries])         # a new matrix: scaled in place
            K.data *= np.repeat(inv_rho_e, np.diff(K.indptr))          # rho_i K_t -> K_t, block by block
            order = None
            if BATCH_ORDERING == "subdomain" and K.shape[0] > DENSE_LIMIT and _sparse_backend(K) == "pardiso":
                order = _restricted_order(_subdomain_ordering(layout, cache), entries, layout.n_W)
            factor = _BatchedFactor(K, order)
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
        # a solution beyond the double range (rho 1e-300 against a load of 1e300) is inf here, quietly: the
        # Krylov method that reads it reports the non-finite value as its breakdown (never converged)
        with np.errstate(over="ignore", invalid="ignore"):
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
    fancy-index copies. Where there are more than :data:`GROUPS_LOOP_MAX`
    groups (a general mesh: every subdomain its own group), the groups of one
    member are applied together as one sparse block-diagonal matrix, so that an
    application makes no Python loop over them (a review: 2 us per subdomain and
    call, 7.7 ms per application at 4,096 parts). The shared templates of the
    structured grids keep their GEMMs (their arithmetic, and the thesis tables,
    unchanged).
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
        self._looped = self.parts
        self._batched: sp.csr_matrix | None = None
        if len(self.parts) > GROUPS_LOOP_MAX:
            batch = [p[3] == 1 and p[2] <= BATCH_MAX_N for p in self.parts]
            if sum(batch) > 1:
                self._looped = [p for p, b in zip(self.parts, batch) if not b]
                self._batched = _block_diagonal([p for p, b in zip(self.parts, batch) if b], self.size)

    def apply(self, xs: np.ndarray) -> np.ndarray:
        """ys = blockdiag(s_i A_t) xs for a compact vector xs = x[flat], shape (size,)."""
        ys = self._batched @ xs if self._batched is not None else np.empty(self.size)
        for A, off, n, n_m, scale in self._looped:
            out = ys[off:off + n * n_m].reshape(n, n_m)
            np.matmul(A, xs[off:off + n * n_m].reshape(n, n_m), out=out)
            out *= scale
        return ys


#: Groups of :class:`DenseBlocks` applied one GEMM each; beyond, the one-member groups are batched.
GROUPS_LOOP_MAX = 32
#: Largest one-member block batched into the sparse block-diagonal matrix (larger ones keep their GEMV).
BATCH_MAX_N = 128


def _block_diagonal(parts, size: int) -> sp.csr_matrix:
    """The one-member ``parts`` of :class:`DenseBlocks` (each ``(A, off, n, 1, scale)``, in increasing ``off``)
    as one sparse matrix of shape (size, size), s A at rows and columns off .. off + n: one product applies
    them all. Its arrays are filled in place (the entries and int32 columns: 1.5x the blocks; a COO build
    peaked at 8.5x; a review)."""
    nnz = sum(n * n for _, _, n, _, _ in parts)
    data = np.empty(nnz)
    indices = np.empty(nnz, dtype=np.int32 if size < 2**31 else np.int64)
    row_nnz = np.zeros(size + 1, dtype=np.int64)
    at = 0
    for A, off, n, _, scale in parts:
        np.multiply(A, scale[0], out=data[at:at + n * n].reshape(n, n))
        indices[at:at + n * n].reshape(n, n)[:] = np.arange(off, off + n)
        row_nnz[off + 1:off + n + 1] = n
        at += n * n
    return sp.csr_matrix((data, indices, np.cumsum(row_nnz)), shape=(size, size))
