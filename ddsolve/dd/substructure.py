"""The unassembled space W = prod_i W^(i) and the operators built on it.

:class:`Substructures` lays out all subdomain vectors one after the other in a
single array of length n_W ("W vectors"), Dirichlet nodes removed. Everything
the solvers need is derived from the scene here, once:

* the local-to-global map (the restriction R of Section 2.3 as an index array),
* the block-diagonal stiffness diag(rho_i K_t) as one sparse matrix,
* interface classification by multiplicity: interior (one subdomain), edge
  (two), vertex (three or more, or two on the boundary of the body: the ends
  of local edges that lie on the body's boundary, Section 3.4), completed on
  irregular partitions so that no floating subdomain keeps a kernel,
* the delta-dagger scaling of Section 2.3 (rho-scaling with exponent gamma;
  multiplicity scaling is rho = 1),
* fully redundant jump operators B and their scaled versions B_D.
"""
from __future__ import annotations

import itertools
import logging

from scipy.sparse import csgraph

import numpy as np
import scipy.sparse as sp

from ..options import PRIMALS
from ..scene.assembly import LocalProblems

log = logging.getLogger(__name__)

#: Primal constraints of FETI-DP / BDDC (``Substructures(primal=...)``).
PRIMAL_KINDS = PRIMALS



def rho_powers(rho: np.ndarray, gamma: float, group: np.ndarray, n_groups: int) -> np.ndarray:
    """rho^gamma of each entry, or, where that over- or underflows (rho^gamma = 1e1200), the same ratios
    within each group (the copies of a node) scaled to a largest value of 1, from gamma log(rho).

    Parameters
    ----------
    rho : ndarray, shape (n,)
        The coefficient of each entry (> 0).
    gamma : float
        The exponent of the rho-scaling (Section 2.3).
    group : ndarray of int, shape (n,)
        The group of each entry, in [0, n_groups).

    Returns
    -------
    ndarray, shape (n,)
        Positive weights whose ratios within a group are those of rho^gamma. Where gamma log(rho) itself
        overflows (gamma 1e308: inf - inf), the largest entries of a group get 1 and the others 0.
    """
    with np.errstate(over="ignore", under="ignore"):
        weight = rho ** gamma
    if np.all((weight > 0.0) & np.isfinite(weight)):
        return weight
    with np.errstate(over="ignore"):
        log_w = gamma * np.log(rho)
    top = np.full(n_groups, -np.inf)
    np.maximum.at(top, group, log_w)
    top_w = top[group]
    with np.errstate(invalid="ignore"):
        return np.where(log_w == top_w, 1.0, np.exp(log_w - top_w))

class Substructures:
    """Layout of W vectors and subdomain data of an assembled scene.

    Parameters
    ----------
    local : LocalProblems
        Assembled scene.
    scaling : {"rho", "multiplicity"}
        Weights delta-dagger of Section 2.3.
    gamma : float
        Exponent of the rho-scaling, gamma >= 1/2.
    templates : bool
        Share local matrices and factorizations between subdomains that are
        translates (``LocalProblems.template``). ``False`` treats every
        subdomain as distinct, as on an unstructured mesh: the solvers then
        factor all subdomains together, one block-diagonal factorization per
        kind (:class:`ddsolve.dd.local.BatchedSolver`). Same operators, same
        iterates up to rounding.
    primal : {"vertices", "vertices+edges"}
        Primal constraints of FETI-DP and BDDC: the cross points, completed by
        the rule of :meth:`_anchor_floating` where a floating subdomain would
        keep a kernel (irregular partitions); with ``"vertices+edges"`` also
        the average over every edge (:mod:`ddsolve.dd.edges`, a change of
        basis: the solvers work on :meth:`primal_space`).

    Attributes
    ----------
    n_sub, n_W, ndof : int
        Subdomains, length of W vectors, global (Dirichlet-free) dofs.
    offsets : ndarray, shape (n_sub + 1,)
        Subdomain s owns W entries offsets[s]:offsets[s+1].
    sub_of_W, local_index, node_of_W, l2g : ndarray, shape (n_W,)
        Subdomain, template-local node index, global node and global dof of
        each W entry.
    multiplicity : ndarray, shape (n_W,)
        Number of subdomains sharing the entry's node.
    interface, vertex, floating_sub : ndarray of bool
        Interface and primal ("vertex") W entries; subdomains without Dirichlet nodes.
    cross_point : ndarray of bool, shape (n_W,)
        Entries of nodes shared by three or more subdomains, or by two on the
        body boundary (Section 3.4); ``vertex`` is this set plus the nodes
        added by :meth:`_anchor_floating`.
    n_primal : int
        Number of primal dofs: distinct global dofs of ``vertex``, plus the
        number of edges with ``primal="vertices+edges"``.
    edge_weights : ndarray of float, shape (n_nodes,), or None
        Node weights of the edge averages (:func:`ddsolve.dd.edges.find_edges`); None: nodal.
    edge_candidates : ndarray of bool, shape (n_W,), or None
        The entries that may lie on an edge; None: ``interface & ~vertex`` (2D). Set with
        ``vertex`` from :func:`ddsolve.dd.edges.subdomain_edges_3d` for 3D edge averages.
    ordering_anchors : ndarray of int, shape (n_W, m), or None
        For the fill-reducing order of the batched factorizations only
        (:func:`ddsolve.dd.local._anchored_order`): W entries of the same subdomain
        (-1 padded) before the first of which each entry is eliminated; the nested
        dissection runs on the entries that anchor to themselves. None: on all entries.
    delta : ndarray, shape (n_W,)
        delta-dagger_i(x) = rho_i^gamma / sum_{j in N_x} rho_j^gamma.
    K_W : scipy.sparse.csr_matrix, shape (n_W, n_W)
        diag(A^(i)), local matrices with Dirichlet rows and columns removed.
    f_W : ndarray, shape (n_W,)
        Stacked local loads f^(i).
    """

    def __init__(self, local: LocalProblems, scaling: str = "rho", gamma: float = 1.0,
                 templates: bool = True, primal: str = "vertices") -> None:
        if primal not in PRIMAL_KINDS:
            raise ValueError(f"primal: expected one of {PRIMAL_KINDS}, got {primal!r}")
        scene = local.scene
        self.local = local
        self.scene = scene
        self.n_sub = scene.n_subdomains
        self.templates = bool(templates)
        if templates:
            self.template = local.template
            self.stiffness = local.stiffness
            self.batch_local = None         # decided by the solvers (many distinct subdomains: batched)
        else:                               # every subdomain its own template (unstructured behaviour)
            self.template = np.arange(self.n_sub)
            self.stiffness = [local.stiffness[t] for t in local.template]
            self.batch_local = True
        full_off, keep = self._layout(scene, local.nodes, primal)
        self._full_offsets, self._kept = full_off, keep
        self._edges = None
        self._primal_space = None
        self.edge_weights = None            # node weights of the edge averages (ddsolve.dd.edges); None: nodal
        self.edge_candidates = None         # W entries that may lie on an edge; None: interface & ~vertex (2D)
        self.ordering_anchors = None        # nested dissection on all entries (ddsolve.dd.local)
        self._edges_in_vertex = False       # True on the transformed copy: the representatives are in ``vertex``
        self.scaling = scaling
        self.gamma = float(gamma)
        self.delta = self.scaling_weights(scaling, gamma)

        self.K_W = self._block_diagonal(full_off, keep)
        f_full = np.concatenate(local.loads)
        self.f_W = f_full[keep]
        self._free_local = [self.local_index[self.offsets[s]:self.offsets[s + 1]] for s in range(self.n_sub)]

    def _layout(self, scene, nodes: list[np.ndarray], primal: str) -> tuple[np.ndarray, np.ndarray]:
        """The W layout and the interface classification of ``scene`` (shared with ddsolve.parallel).

        Sets ``rho``, ``body_of_sub``, ``node_of_W``, ``sub_of_W``, ``local_index``, ``n_W``,
        ``offsets``, ``floating_sub``, ``dof_of_node``, ``ndof``, ``l2g``, ``multiplicity``,
        ``interface``, ``cross_point``, ``vertex`` and ``primal``.

        Parameters
        ----------
        scene : Scene
        nodes : list of ndarray
            Global node numbers of each subdomain, in local order.
        primal : str

        Returns
        -------
        full_off : ndarray, shape (n_sub + 1,)
            Offsets of the subdomains in the node lists with Dirichlet nodes.
        keep : ndarray of bool
            The entries of those lists that are free (the W entries).
        """
        self.rho = np.asarray(scene.rho, dtype=float)
        self.body_of_sub = scene.subdomain_body

        sizes_full = np.array([len(nd) for nd in nodes])
        full_off = np.concatenate([[0], np.cumsum(sizes_full)])
        node_full = np.concatenate(nodes)
        sub_full = np.repeat(np.arange(self.n_sub), sizes_full)
        local_full = np.arange(full_off[-1]) - full_off[sub_full]
        keep = ~scene.dirichlet[node_full]

        self.node_of_W = node_full[keep]
        self.sub_of_W = sub_full[keep]
        self.local_index = local_full[keep]
        self.n_W = int(keep.sum())
        counts = np.bincount(self.sub_of_W, minlength=self.n_sub)
        self.offsets = np.concatenate([[0], np.cumsum(counts)])
        self.floating_sub = np.bincount(sub_full, weights=scene.dirichlet[node_full],
                                        minlength=self.n_sub) == 0

        dof_of_node = np.full(scene.n_nodes, -1, dtype=np.int64)
        free_nodes = np.flatnonzero(~scene.dirichlet)
        dof_of_node[free_nodes] = np.arange(free_nodes.size)
        self.dof_of_node = dof_of_node
        self.ndof = int(free_nodes.size)
        self.l2g = dof_of_node[self.node_of_W]

        self.multiplicity = np.bincount(self.node_of_W, minlength=scene.n_nodes)[self.node_of_W]
        self.interface = self.multiplicity > 1
        # a node belongs to one body (each body has its own copies), so the mask of all bodies at once is each
        # body's (a loop over the bodies made an O(n) pass each: O(n_bodies n); a review)
        on_body_boundary = scene.boundary_node_mask()[self.node_of_W]
        self.cross_point = (self.multiplicity >= 3) | ((self.multiplicity == 2) & on_body_boundary)
        self.vertex = self._anchor_floating(self.cross_point.copy())
        self.primal = primal

        return full_off, keep

    # ------------------------------------------------------------------ primal
    def _primal_components(self, vertex: np.ndarray) -> np.ndarray:
        """Connected components of the subdomain graph joined by shared primal nodes, (n_sub,)."""
        pw = np.flatnonzero(vertex)
        n = self.n_sub + self.scene.n_nodes          # bipartite graph: subdomains and primal nodes
        G = sp.coo_matrix((np.ones(pw.size), (self.sub_of_W[pw], self.n_sub + self.node_of_W[pw])),
                          shape=(n, n))
        _, label = csgraph.connected_components(G, directed=False)
        return label[:self.n_sub]

    def _anchor_floating(self, vertex: np.ndarray) -> np.ndarray:
        """Add primal nodes until no floating subdomain keeps a kernel in A~ (2.17).

        A~ (subdomains coupled only at primal nodes) is singular exactly on
        the connected components of the "primal graph" (subdomains joined by
        shared primal nodes) that contain no subdomain with Dirichlet nodes;
        with cross points alone this happens on irregular partitions (an
        interface that ends on the Dirichlet boundary or on another body, a
        subdomain touching only one neighbour). Rule: while some component of
        a body has no Dirichlet subdomain and is not the whole body (a
        floating body, handled by the solvers that pin it), promote to primal
        the interface node of that component, shared with a subdomain outside
        it, of largest multiplicity (ties: smallest node id), preferring
        nodes shared with a component that has Dirichlet nodes. Every
        floating subdomain then has at least one primal node. Structured
        scenes are unchanged (their cross points already connect each body).
        Vectorised per round; the rounds are few (each joins every
        unanchored component to a neighbour).
        """
        subs_in_body = np.bincount(self.body_of_sub, minlength=self.scene.n_bodies)
        for _ in range(self.n_sub):
            comp = self._primal_components(vertex)
            n_comp = int(comp.max()) + 1 if comp.size else 0
            anchored = np.bincount(comp, weights=~self.floating_sub, minlength=n_comp) > 0
            size = np.bincount(comp, minlength=n_comp)
            body_of_comp = np.zeros(n_comp, dtype=np.int64)
            body_of_comp[comp] = self.body_of_sub
            bad = ~anchored & (size < subs_in_body[body_of_comp])
            if not bad.any():
                return vertex
            # candidate W entries: interface entries of a bad component whose node is shared with another component
            comp_W = comp[self.sub_of_W]
            node = self.node_of_W
            cmin = np.full(self.scene.n_nodes, n_comp)
            cmax = np.full(self.scene.n_nodes, -1)
            np.minimum.at(cmin, node, comp_W)
            np.maximum.at(cmax, node, comp_W)
            anch_node = np.zeros(self.scene.n_nodes, dtype=bool)
            np.logical_or.at(anch_node, node, anchored[comp_W])
            cand = np.flatnonzero(bad[comp_W] & (cmin[node] != cmax[node]) & ~vertex)
            if cand.size == 0:
                raise ValueError("primal: a floating component of subdomains has no interface node to constrain")
            # best candidate per bad component: anchored neighbour, largest multiplicity, smallest node
            order = np.lexsort((node[cand], -self.multiplicity[cand], ~anch_node[node[cand]], comp_W[cand]))
            cand = cand[order]
            first = np.r_[True, comp_W[cand][1:] != comp_W[cand][:-1]]
            chosen = np.unique(node[cand[first]])
            vertex |= np.isin(node, chosen)
        return vertex

    @property
    def n_primal(self) -> int:
        """Number of primal constraints (distinct primal global dofs, plus the edges if primal)."""
        n_vertices = int(np.unique(self.l2g[self.vertex]).size)
        if self.primal == "vertices+edges" and not self._edges_in_vertex:
            return n_vertices + self.edges.n_edges
        return n_vertices

    @property
    def edges(self):
        """The edges of the decomposition (:func:`ddsolve.dd.edges.find_edges`), found on first use."""
        if self._edges is None:
            from .edges import find_edges
            self._edges = find_edges(self, self.edge_weights, candidates=self.edge_candidates)
        return self._edges

    def primal_space(self):
        """The space FETI-DP and BDDC solve in (:class:`ddsolve.dd.edges.PrimalSpace`), built on first use.

        ``primal="vertices"``: these substructures. ``"vertices+edges"``: the
        change of basis that makes every edge average a primal unknown. Build it
        after the last change of ``delta`` or ``f_W`` (the copy shares them as
        they are then; loads passed to :meth:`PrimalSpace.to_primal` are mapped
        at each call).
        """
        if self._primal_space is None:
            from .edges import PrimalSpace
            self._primal_space = PrimalSpace(self, self.edges if self.primal == "vertices+edges" else None)
        return self._primal_space

    # ------------------------------------------------------------------ layout
    def _block_diagonal(self, full_off: np.ndarray, keep: np.ndarray) -> sp.csr_matrix:
        """diag(rho_i K_t(i)) restricted to free entries, built per template without loops over nodes.

        The CSR arrays are written directly: for all members of a template at once, the
        entries of the canonical K_t whose row and column are free (a (members, nnz_t)
        mask), renumbered to W; the subdomain blocks then follow in subdomain order. O(nnz),
        no sort and no global fancy indexing.
        """
        by_template = np.argsort(self.template, kind="stable")
        t_bounds = np.searchsorted(self.template[by_template], np.arange(len(self.stiffness) + 1))
        cols, vals, row_nnz, block_nnz = [], [], [], []
        index_type = np.int32 if self.n_W < 2**31 - 1 else np.int64
        for t, K in enumerate(self.stiffness):
            members = by_template[t_bounds[t]:t_bounds[t + 1]]
            if members.size == 0:
                continue
            K = sp.csr_matrix(K)
            if not K.has_canonical_format:
                K = K.copy()
                K.sum_duplicates()
            n = K.shape[0]
            free = keep[full_off[members][:, None] + np.arange(n)]                  # (g, n)
            row_of_entry = np.repeat(np.arange(n), np.diff(K.indptr))
            kept = free[:, row_of_entry] & free[:, K.indices]                       # (g, nnz_t)
            w_index = (np.cumsum(free, axis=1, dtype=index_type) - 1
                       + self.offsets[members][:, None].astype(index_type))         # W index of local node
            cols.append(w_index[:, K.indices][kept])
            with np.errstate(over="ignore"):           # rho near the largest double: refused by the caller
                vals.append((K.data[None, :] * self.rho[members][:, None])[kept])
            if np.all(np.diff(K.indptr) > 0):                                       # entries of each row
                counts = np.add.reduceat(kept, K.indptr[:-1], axis=1, dtype=np.int64)
            else:
                csum = np.concatenate([np.zeros((members.size, 1), dtype=np.int64),
                                       np.cumsum(kept, axis=1)], axis=1)
                counts = csum[:, K.indptr[1:]] - csum[:, K.indptr[:-1]]
            row_nnz.append(counts[free])
            block_nnz.append(counts.sum(axis=1))
        cols, vals, row_nnz = np.concatenate(cols), np.concatenate(vals), np.concatenate(row_nnz)
        if np.any(by_template[1:] < by_template[:-1]):      # blocks back into subdomain order
            block_nnz = np.concatenate(block_nnz)
            n_free = np.diff(self.offsets)[by_template]
            entry_perm = _block_permutation(block_nnz, by_template)
            row_perm = _block_permutation(n_free, by_template)
            cols, vals, row_nnz = cols[entry_perm], vals[entry_perm], row_nnz[row_perm]
        indptr = np.concatenate([[0], np.cumsum(row_nnz)])
        return sp.csr_matrix((vals, cols, indptr), shape=(self.n_W, self.n_W))

    def position(self, s: int, loc: np.ndarray) -> np.ndarray:
        """W positions of template-local (free) indices ``loc`` of subdomain s."""
        return self.offsets[s] + np.searchsorted(self._free_local[s], loc)

    def positions(self, members: np.ndarray, loc: np.ndarray) -> np.ndarray:
        """:meth:`position` of ``loc`` (k,) for each of ``members`` (m,), shape (k, m), by one search over the
        (subdomain, local index) keys of all W entries (one call per member was a Python loop over the
        subdomains: 262,144 calls, 2 s, for 256 x 256 subdomains; a review)."""
        members = np.asarray(members, dtype=np.int64)
        keys = getattr(self, "_position_keys", None)
        # built from these very arrays (a transformed copy with other arrays builds its own)
        if keys is None or keys[0] is not self.sub_of_W or keys[1] is not self.local_index:
            width = int(self.local_index.max(initial=-1)) + 1
            key = self.sub_of_W.astype(np.int64) * width + self.local_index
            keys = self._position_keys = (self.sub_of_W, self.local_index,
                                          key if bool(np.all(key[1:] > key[:-1])) else None, width)
        _, _, key, width = keys
        if key is None:                              # local indices not sorted within a subdomain
            return np.stack([self.position(int(s), loc) for s in members], axis=1).reshape(len(loc), members.size)
        return np.searchsorted(key, members[None, :] * width + np.asarray(loc, dtype=np.int64)[:, None])

    def scaling_weights(self, scaling: str, gamma: float = 1.0) -> np.ndarray:
        """delta-dagger weights of Section 2.3 for every W entry.

        delta_i(x) = rho_i^gamma / sum_{j in N_x} rho_j^gamma, with rho = 1
        for ``"multiplicity"`` scaling (then delta_i(x) = 1 / |N_x|).
        """
        if scaling == "multiplicity":
            weight = np.ones(self.n_W)
        else:
            weight = rho_powers(self.rho[self.sub_of_W], gamma, self.node_of_W, self.scene.n_nodes)
        total = np.bincount(self.node_of_W, weights=weight, minlength=self.scene.n_nodes)
        return weight / total[self.node_of_W]

    # ------------------------------------------------------------- restriction
    def restrict(self, u: np.ndarray) -> np.ndarray:
        """R u: global vector (ndof,) -> W vector (n_W,)."""
        return u[self.l2g]

    def assemble_vector(self, w: np.ndarray) -> np.ndarray:
        """R^T w: sum the subdomain contributions, (n_W,) -> (ndof,)."""
        return np.bincount(self.l2g, weights=w, minlength=self.ndof)

    def average(self, w: np.ndarray) -> np.ndarray:
        """R_D^T w: delta-weighted average of the subdomain copies, (n_W,) -> (ndof,)."""
        return np.bincount(self.l2g, weights=self.delta * w, minlength=self.ndof)

    def global_matrix(self) -> sp.csr_matrix:
        """Assembled stiffness R^T diag(A^(i)) R, shape (ndof, ndof) (for direct solves and checks)."""
        R = sp.csr_matrix((np.ones(self.n_W), (np.arange(self.n_W), self.l2g)), shape=(self.n_W, self.ndof))
        return (R.T @ self.K_W @ R).tocsr()

    # ---------------------------------------------------------- jump operators
    def jump_operators(self, mask: np.ndarray) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """Fully redundant jump operator B and its scaled version B_D (Section 2.3).

        Every pair (i, j), i < j, of subdomains sharing a node x whose W entries
        are selected by ``mask`` gets one multiplier row: +1 on (i, x), -1 on
        (j, x). In B_D the entry of subdomain i is multiplied by delta_j(x) and
        that of j by delta_i(x).

        Parameters
        ----------
        mask : ndarray of bool, shape (n_W,)

        Returns
        -------
        B, B_D : scipy.sparse.csr_matrix, shape (n_lambda, n_W)
        """
        idx = np.flatnonzero(mask & self.interface)
        order = idx[np.lexsort((self.sub_of_W[idx], self.node_of_W[idx]))]
        node = self.node_of_W[order]
        starts = np.flatnonzero(np.r_[True, node[1:] != node[:-1]])
        sizes = np.diff(np.r_[starts, node.size])
        first, second = [], []
        for k in np.unique(sizes):
            if k < 2:
                continue
            group_starts = starts[sizes == k]
            for a, b in itertools.combinations(range(int(k)), 2):
                first.append(order[group_starts + a])
                second.append(order[group_starts + b])
        if first:
            pa, pb = np.concatenate(first), np.concatenate(second)
            srt = np.lexsort((self.node_of_W[pb], self.node_of_W[pa]))
            pa, pb = pa[srt], pb[srt]
        else:
            pa = pb = np.zeros(0, dtype=np.int64)
        n_lam = pa.size
        rows = np.r_[np.arange(n_lam), np.arange(n_lam)]
        cols = np.r_[pa, pb]
        B = sp.csr_matrix((np.r_[np.ones(n_lam), -np.ones(n_lam)], (rows, cols)), shape=(n_lam, self.n_W))
        B_D = sp.csr_matrix((np.r_[self.delta[pb], -self.delta[pa]], (rows, cols)), shape=(n_lam, self.n_W))
        return B, B_D

    def kernel_basis(self) -> sp.csr_matrix:
        """R: orthonormal basis of ker(diag(A^(i))), constants on floating subdomains.

        Returns
        -------
        scipy.sparse.csr_matrix, shape (n_W, n_floating)
        """
        floating = np.flatnonzero(self.floating_sub)
        col_of_sub = np.full(self.n_sub, -1)
        col_of_sub[floating] = np.arange(floating.size)
        entries = np.flatnonzero(self.floating_sub[self.sub_of_W])
        sub = self.sub_of_W[entries]
        size = np.diff(self.offsets)[sub]
        return sp.csr_matrix((1.0 / np.sqrt(size), (entries, col_of_sub[sub])), shape=(self.n_W, floating.size))


def _block_permutation(sizes: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Gather index that puts blocks stored in the order ``order`` (block k of length
    ``sizes[k]`` belongs to item ``order[k]``) back into item order."""
    src_start = np.concatenate([[0], np.cumsum(sizes)])[:-1]
    item_sizes = np.empty_like(sizes)
    item_sizes[order] = sizes
    item_src = np.empty_like(src_start)
    item_src[order] = src_start
    dst_start = np.concatenate([[0], np.cumsum(item_sizes)])[:-1]
    return np.repeat(item_src - dst_start, item_sizes) + np.arange(int(item_sizes.sum()))
