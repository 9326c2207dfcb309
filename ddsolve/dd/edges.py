"""Edge-average primal constraints of FETI-DP and BDDC by a change of basis.

An *edge* is a connected set of interface nodes, primal vertices excluded,
shared by exactly the same set of (two or more) subdomains of one body. With
``primal="vertices+edges"`` the average of u over every edge becomes a primal
(coarse) unknown in addition to the vertices.

Design: the change of basis of Klawonn & Widlund (2006, "Dual-primal FETI
methods for linear elasticity", CPAM 59) and Li & Widlund (2006, "FETI-DP,
BDDC, and block Cholesky methods", IJNME 66), not explicit constraints. On an
edge E with nodes e_0 < e_1 < ... < e_{m-1} (global node numbers; e_0 is the
*representative*) and a shortest-path tree of E rooted at e_0 (parent p(c) of
every other node c, along couplings of the subdomain matrices) the new local
variables u^ are defined by u = T u^ with the columns

    T e_{e_0} = sum_j e_{e_j}   (the constant on E),
    T e_c     = e_c - e_{p(c)}  (c != e_0, zero sum),

so that sum_j u_{e_j} = m u^_{e_0}: the representative's new variable *is* the
edge average, and T is the identity off the edges. The tree keeps T^T K T
sparse (a star around e_0, every column e_c - e_{e_0}, would couple all dofs of
an edge: measured +70 % nonzeros at H/h = 32). Why this design:

* the primal unknowns stay node-like (one W entry per subdomain copy of the
  representative), so :class:`ddsolve.dd.operators.PrimalConstrainedSolver`,
  the batched factorizations, the explicit Schur/interface blocks and the
  jump operators are used unchanged on the transformed subdomain matrices
  K^_i = T_i^T K_i T_i (formed once per distinct (template, local edge
  pattern) before the factorizations, so translates keep sharing them);
* T is the same function of the global node values on every subdomain sharing
  the edge, so the jumps of u^ vanish iff those of u do: B keeps its form on
  the non-primal transformed entries; the delta-dagger weights are made
  constant along each edge (their mean; rho and multiplicity scaling are so
  already), so that scaling commutes with T;
* the back-maps are one sparse product each: loads f^ = T^T f, solutions
  u = T u^ (``T_W`` is block diagonal over the subdomains, applied to the
  whole W vector at once).

Weighted edges (high-order bases). The unweighted sum above is the mean of u
along E only for nodal (P1/Q1) bases. For a hierarchical basis (NGSolve's H1
of order p >= 2: vertex hats and edge bubbles) the average is

    u_E = sum_j w_j u_{e_j} / sum_j w_j,   w_j = int_E phi_{e_j} ds

(w_j > 0 for the hats, w_j = 0 for bubbles that integrate to zero along E;
``find_edges(sub, node_weight=w)``). Then the representative e_0 is the
smallest node of non-zero weight, and with a(c) the nearest tree ancestor of
c of non-zero weight (the root has weight)

    T e_{e_0} = sum_j e_{e_j},
    T e_c     = e_c - (w_c / w_{a(c)}) e_{a(c)}   (w_c != 0),
    T e_c     = e_c                              (w_c  = 0),

so that w^T T e_c = 0 for c != e_0 and w^T T e_{e_0} = sum_j w_j: the
representative's new variable is u_E. The weights are a property of the
global node (the same on every subdomain), so T keeps the properties above;
a(c) = p(c) except below zero-weight nodes, so T^T K T stays tree-sparse. The
constrained space {w^T u_i equal on all subdomains of E} and hence the
preconditioner do not depend on the choice of the representative column.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from ..scene.scene import unique_row_labels


@dataclass(frozen=True)
class Edges:
    """The edges of a decomposition.

    Attributes
    ----------
    label : ndarray of int, shape (n_W,)
        Edge of every W entry (-1: not on an edge).
    representative : ndarray of bool, shape (n_W,)
        Entries of the representative node (smallest global node) of their edge.
    rep_entry : ndarray of int, shape (n_W,)
        W entry of the representative in the same subdomain (-1 off the edges).
    parent_entry : ndarray of int, shape (n_W,)
        W entry, in the same subdomain, of the parent of the entry's node in a shortest-path
        tree of its edge rooted at the representative (-1 off the edges and at the root).
    n_edges : int
    anchor_entry : ndarray of int, shape (n_W,), or None
        Weighted edges only: W entry, in the same subdomain, of the nearest tree ancestor of the
        entry's node whose weight is not zero (-1 off the edges, at the root and where the entry's
        own weight is zero). None: ``parent_entry`` (unweighted edges).
    coef : ndarray of float, shape (n_W,), or None
        Weighted edges only: w_c / w_anchor(c) of every non-representative edge entry (0 where
        w_c = 0 and off the edges). None: 1 (unweighted edges).
    """

    label: np.ndarray
    representative: np.ndarray
    rep_entry: np.ndarray
    parent_entry: np.ndarray
    n_edges: int
    anchor_entry: np.ndarray | None = None
    coef: np.ndarray | None = None


def find_edges(sub, node_weight: np.ndarray | None = None, tol: float = 1e-10,
               candidates: np.ndarray | None = None) -> Edges:
    """The edges of ``sub``: non-vertex interface nodes grouped by their subdomain set, split into
    connected pieces (nodes coupled by a stored entry of a subdomain matrix), O(n log n).

    Parameters
    ----------
    sub : Substructures
    node_weight : ndarray of float, shape (n_nodes,), optional
        w_j of every global node: the integral of its basis function along its edge (see the module
        docstring, "Weighted edges"). None: the nodal average (w_j = 1), the P1 / Q1 case.
    tol : float
        Weights with |w_j| <= tol * max_E |w| are zero (e.g. odd edge bubbles, rounding).
    candidates : ndarray of bool, shape (n_W,), optional
        The W entries that may lie on an edge (whole nodes, no vertex among them). None:
        ``sub.interface & ~sub.vertex`` (2D: every non-vertex interface node). In 3D the faces
        (nodes of two subdomains) are left out: :func:`subdomain_edges_3d`.

    Returns
    -------
    Edges
    """
    n_W, n_nodes = sub.n_W, sub.scene.n_nodes
    idx = np.flatnonzero(sub.interface & ~sub.vertex if candidates is None else candidates)
    label = np.full(n_W, -1, dtype=np.int64)
    rep = np.zeros(n_W, dtype=bool)
    rep_entry = np.full(n_W, -1, dtype=np.int64)
    parent_entry = np.full(n_W, -1, dtype=np.int64)
    if idx.size == 0:
        return Edges(label, rep, rep_entry, parent_entry, 0)
    G, cand_nodes, edge_of_node, n_edges = _node_classes(sub, idx)
    rep_node = np.full(n_edges, n_nodes, dtype=np.int64)
    weight = None
    if node_weight is None:
        np.minimum.at(rep_node, edge_of_node[cand_nodes], cand_nodes)
    else:
        weight = _clean_weights(np.asarray(node_weight, dtype=float), cand_nodes, edge_of_node, n_edges, tol)
        nonzero = cand_nodes[weight[cand_nodes] != 0]
        np.minimum.at(rep_node, edge_of_node[nonzero], nonzero)     # the representative carries weight
    label[idx] = edge_of_node[sub.node_of_W[idx]]
    rep[idx] = sub.node_of_W[idx] == rep_node[label[idx]]
    # representative entry of each edge entry in its own subdomain: look up (subdomain, edge)
    r = np.flatnonzero(rep)
    key_r = sub.sub_of_W[r] * n_edges + label[r]
    srt = np.argsort(key_r)
    key_e = sub.sub_of_W[idx] * n_edges + label[idx]
    rep_entry[idx] = r[srt[np.searchsorted(key_r[srt], key_e)]]
    # parents: one multi-source shortest-path search from all representatives (each edge holds one)
    _, pred, _ = csgraph.dijkstra(G.tocsr(), directed=False, indices=rep_node, unweighted=True,
                                  return_predecessors=True, min_only=True)
    child = idx[~rep[idx]]
    parent_node = pred[sub.node_of_W[child]]
    if np.any(parent_node < 0):
        raise ValueError("primal: an edge node is not connected to its representative")
    key_w = sub.sub_of_W[idx] * n_nodes + sub.node_of_W[idx]
    srt_w = np.argsort(key_w)
    parent_entry[child] = idx[srt_w[np.searchsorted(key_w[srt_w], sub.sub_of_W[child] * n_nodes + parent_node)]]
    if weight is None:
        return Edges(label, rep, rep_entry, parent_entry, n_edges)
    # anchors: the nearest ancestor of non-zero weight (pointer jumping; the root has weight)
    child_node = sub.node_of_W[child]
    anchor_node = parent_node.copy()
    todo = weight[anchor_node] == 0
    while todo.any():
        anchor_node[todo] = pred[anchor_node[todo]]
        todo = weight[anchor_node] == 0
    live = weight[child_node] != 0
    anchor_entry = np.full(n_W, -1, dtype=np.int64)
    coef = np.zeros(n_W)
    anchor_entry[child[live]] = idx[srt_w[np.searchsorted(
        key_w[srt_w], sub.sub_of_W[child[live]] * n_nodes + anchor_node[live])]]
    coef[child[live]] = weight[child_node[live]] / weight[anchor_node[live]]
    return Edges(label, rep, rep_entry, parent_entry, n_edges, anchor_entry, coef)


def _node_classes(sub, idx: np.ndarray) -> tuple[sp.coo_matrix, np.ndarray, np.ndarray, int]:
    """The nodes of the W entries ``idx`` grouped by subdomain set and split into connected pieces.

    Returns
    -------
    G : scipy.sparse.coo_matrix, shape (n_nodes, n_nodes)
        Couplings (stored entries of a subdomain matrix) between nodes of the same set.
    cand_nodes : ndarray of int
        The distinct nodes of ``idx``, sorted.
    class_of_node : ndarray of int, shape (n_nodes,)
        Piece of every node (-1: not in ``idx``).
    n_classes : int
    """
    n_nodes = sub.scene.n_nodes
    # subdomain set of every candidate node: its subdomains sorted, one row per node of each multiplicity
    order = idx[np.lexsort((sub.sub_of_W[idx], sub.node_of_W[idx]))]
    node_sorted = sub.node_of_W[order]
    starts = np.flatnonzero(np.r_[True, node_sorted[1:] != node_sorted[:-1]])
    sizes = np.diff(np.r_[starts, node_sorted.size])
    set_of_node = np.full(n_nodes, -1, dtype=np.int64)
    n_sets = 0
    for m in np.unique(sizes):
        first = starts[sizes == m]
        subs = sub.sub_of_W[order[first[:, None] + np.arange(m)[None, :]]]        # (k, m), sorted rows
        inverse = unique_row_labels(subs)
        set_of_node[node_sorted[first]] = n_sets + inverse
        n_sets += int(inverse.max()) + 1
    # connected pieces: candidate nodes of the same set coupled in some subdomain matrix
    Kc = sub.K_W[idx][:, idx].tocoo()
    a, b = sub.node_of_W[idx[Kc.row]], sub.node_of_W[idx[Kc.col]]
    same = set_of_node[a] == set_of_node[b]
    G = sp.coo_matrix((np.ones(int(same.sum())), (a[same], b[same])), shape=(n_nodes, n_nodes))
    _, comp = csgraph.connected_components(G, directed=False)
    cand_nodes = np.unique(sub.node_of_W[idx])
    class_ids, class_of_cand = np.unique(comp[cand_nodes], return_inverse=True)
    class_of_node = np.full(n_nodes, -1, dtype=np.int64)
    class_of_node[cand_nodes] = class_of_cand.ravel()
    return G, cand_nodes, class_of_node, int(class_ids.size)


def subdomain_edges_3d(sub) -> tuple[np.ndarray, np.ndarray]:
    """Subdomain vertices and edge candidates of a 3D decomposition, for edge averages (2.22).

    In 3D the nodes shared by three or more subdomains (or by two on the body's
    boundary: ``sub.cross_point``) form the subdomain *edges*, curves of
    nodes with the same subdomain set, and their end points. Section 2.6 of
    the thesis (after Klawonn, Widlund & Dryja 2002) makes the vertex values
    and the edge averages primal: this splits ``cross_point`` into the pieces
    of :func:`_node_classes` of a single node (the *vertices*) and those of
    several nodes (the edges, whose averages :class:`PrimalSpace` makes
    primal). The faces (two subdomains) stay dual. The anchors that
    :meth:`~ddsolve.dd.substructure.Substructures._anchor_floating` added to
    ``sub.vertex`` (face nodes where a component of subdomains would float
    with all of its edges primal) stay vertices, so A~ is as regular as with
    every edge node primal.

    Parameters
    ----------
    sub : Substructures
        With ``vertex`` as built (``cross_point`` plus anchors).

    Returns
    -------
    vertex : ndarray of bool, shape (n_W,)
        The primal vertices.
    candidates : ndarray of bool, shape (n_W,)
        The entries on the edges: the ``candidates`` of :func:`find_edges`.
    """
    idx = np.flatnonzero(sub.cross_point)
    vertex = sub.vertex & ~sub.cross_point                   # the anchors
    if idx.size:
        _, cand_nodes, class_of_node, n_classes = _node_classes(sub, idx)
        size = np.bincount(class_of_node[cand_nodes], minlength=n_classes)
        single = np.zeros(sub.scene.n_nodes, dtype=bool)
        single[cand_nodes] = size[class_of_node[cand_nodes]] == 1
        vertex = vertex | single[sub.node_of_W]
    return vertex, sub.cross_point & ~vertex


def _clean_weights(node_weight: np.ndarray, cand_nodes: np.ndarray, edge_of_node: np.ndarray, n_edges: int,
                   tol: float) -> np.ndarray:
    """Node weights with |w_j| <= tol * max_E |w| set to 0, and 1 on edges without any weight, (n_nodes,)."""
    if node_weight.shape != edge_of_node.shape:
        raise ValueError(f"primal: expected {edge_of_node.size} node weights, got shape {node_weight.shape}")
    w = node_weight[cand_nodes]
    e = edge_of_node[cand_nodes]
    scale = np.zeros(n_edges)
    np.maximum.at(scale, e, np.abs(w))
    w = np.where(np.abs(w) > tol * scale[e], w, 0.0)
    w = np.where(scale[e] > 0, w, 1.0)          # no weight on an edge: its nodal average
    out = np.zeros(node_weight.size)
    out[cand_nodes] = w
    return out


def basis_matrix(n: int, entries: np.ndarray, reps: np.ndarray, parents: np.ndarray,
                 coef: np.ndarray | None = None) -> sp.csr_matrix:
    """T of the module docstring on a space of dimension n: identity, plus T[e, r] = 1 and
    T[p, e] = -1 (weighted: -coef[e], omitted where coef is 0) for every non-representative
    edge entry e with representative r and parent (weighted: anchor) p (arrays of equal size)."""
    coef = np.ones(entries.size) if coef is None else coef
    live = coef != 0
    rows = np.r_[np.arange(n), entries, parents[live]]
    cols = np.r_[np.arange(n), reps, entries[live]]
    vals = np.r_[np.ones(n), np.ones(entries.size), -coef[live]]
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


def _transformed_blocks(blocks: list, sub_of_e: np.ndarray, loc_e: np.ndarray, loc_r: np.ndarray,
                       loc_p: np.ndarray, coef: np.ndarray | None) -> list[sp.csr_matrix]:
    """T_i^T K_i T_i of every block K_i at once: one triple product of block-diagonal matrices.

    Parameters
    ----------
    blocks : list of sparse matrices
        K_i, one per subdomain (in subdomain order), on the template-local index space.
    sub_of_e : ndarray of int, shape (m,)
        Subdomain of every non-representative edge entry; ``loc_e``, ``loc_r``, ``loc_p``
        (shape (m,)) its template-local index, its representative's and its parent's
        (anchor's), and ``coef`` its weight (None: unweighted), as for :func:`basis_matrix`.

    Returns
    -------
    list of csr_matrix
        The transformed blocks, in subdomain order.
    """
    from ..scene.assembly import diagonal_block

    csr = [sp.csr_matrix(K) for K in blocks]
    sizes = np.array([K.shape[0] for K in csr], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    nnz_offsets = np.concatenate([[0], np.cumsum([K.nnz for K in csr])])
    K = sp.csr_matrix((np.concatenate([K.data for K in csr]),
                       np.concatenate([K.indices.astype(np.int64) + offsets[k] for k, K in enumerate(csr)]),
                       np.concatenate([[0]] + [K.indptr[1:].astype(np.int64) + nnz_offsets[k]
                                               for k, K in enumerate(csr)])),
                      shape=(offsets[-1], offsets[-1]))
    shift = offsets[sub_of_e]
    T = basis_matrix(int(offsets[-1]), shift + loc_e, shift + loc_r, shift + loc_p, coef)
    K_hat = (T.T @ K @ T).tocsr()
    return [diagonal_block(K_hat, offsets[k], offsets[k + 1]) for k in range(len(csr))]


def _transformed_templates(s, sub_of_e: np.ndarray, loc_e: np.ndarray, loc_r: np.ndarray, loc_p: np.ndarray,
                           coef: np.ndarray | None) -> tuple[np.ndarray, list[sp.csr_matrix]]:
    """T^T K_t T once per distinct (template t, local edge pattern) of the substructures ``s``.

    The arguments are those of :func:`_transformed_blocks`. Returns the new template of
    every subdomain, shape (n_sub,), and the transformed template matrices.
    """
    bounds = np.searchsorted(sub_of_e, np.arange(s.n_sub + 1))
    new_template = np.empty(s.n_sub, dtype=np.int64)
    stiffness: list[sp.csr_matrix] = []
    seen: dict[bytes, int] = {}
    for k in range(s.n_sub):
        lo, hi = bounds[k], bounds[k + 1]
        t = int(s.template[k])
        key = (t.to_bytes(8, "little") + loc_e[lo:hi].tobytes() + loc_r[lo:hi].tobytes()
               + loc_p[lo:hi].tobytes() + (b"" if coef is None else coef[lo:hi].tobytes()))
        hit = seen.get(key)
        if hit is None:
            K = s.stiffness[t]
            T = basis_matrix(K.shape[0], loc_e[lo:hi], loc_r[lo:hi], loc_p[lo:hi],
                             None if coef is None else coef[lo:hi])
            hit = seen[key] = len(stiffness)
            stiffness.append((T.T @ K @ T).tocsr())
        new_template[k] = hit
    return new_template, stiffness


class PrimalSpace:
    """The W space in which FETI-DP and BDDC solve, and its maps to and from the original basis.

    For ``primal="vertices"`` the identity: ``sub`` is the original
    :class:`~ddsolve.dd.substructure.Substructures`. For ``"vertices+edges"``
    ``sub`` is a copy whose subdomain matrices are K^_i = T_i^T K_i T_i, whose
    loads are T^T f and whose ``vertex`` mask holds the vertices and the edge
    representatives (the edge averages); see the module docstring.

    Attributes
    ----------
    sub : Substructures
        The substructures to solve on.
    T_W : scipy.sparse.csr_matrix or None, shape (n_W, n_W)
        u_W = T_W u^_W (None: identity).
    """

    def __init__(self, original, edges: Edges | None) -> None:
        self.original = original
        self.edges = edges
        if edges is None or edges.n_edges == 0:
            self.T_W = None
            self.sub = original
            if edges is not None:
                self.sub = copy.copy(original)
                self.sub._primal_space = self
            return
        s = original
        e = np.flatnonzero((edges.label >= 0) & ~edges.representative)
        r = edges.rep_entry[e]
        if edges.coef is None:
            par, cf = edges.parent_entry[e], None
        else:                       # weighted: the anchor (-1 where the weight is 0: no entry, use e)
            cf = edges.coef[e]
            par = np.where(cf != 0, edges.anchor_entry[e], e)
        self.T_W = basis_matrix(s.n_W, e, r, par, cf)
        self._T_W_T = self.T_W.T.tocsr()
        view = copy.copy(s)
        view._primal_space = self
        view._edges_in_vertex = True
        view.vertex = s.vertex | edges.representative
        view.delta = self._edge_constant(s.delta, edges)
        loc_e, loc_r, loc_p = s.local_index[e], s.local_index[r], s.local_index[par]
        if np.array_equal(s.template, np.arange(s.n_sub)) and len(s.stiffness) == s.n_sub:
            # every subdomain its own template (unstructured meshes, DDInverse): all blocks in one product
            new_template = np.arange(s.n_sub)
            stiffness = _transformed_blocks(s.stiffness, s.sub_of_W[e], loc_e, loc_r, loc_p, cf)
        else:
            new_template, stiffness = _transformed_templates(s, s.sub_of_W[e], loc_e, loc_r, loc_p, cf)
        view.template = new_template
        view.stiffness = stiffness
        view.K_W = view._block_diagonal(s._full_offsets, s._kept)
        view.f_W = self._T_W_T @ s.f_W
        self.sub = view

    @staticmethod
    def _edge_constant(delta: np.ndarray, edges: Edges) -> np.ndarray:
        """delta-dagger made constant along every edge of every subdomain (its mean there), (n_W,).

        The scaled jumps and the BDDC averaging act on the transformed variables, so the weights
        must not vary along an edge; the means of the copies of a node still sum to one. rho and
        multiplicity scaling are constant along edges already (unchanged up to rounding); the
        per-dof "diagonal" scaling of :class:`ddsolve.ngsolve.DDInverse` becomes an edge-wise one.
        """
        on = np.flatnonzero(edges.label >= 0)
        if on.size == 0:
            return delta
        group = np.unique(edges.rep_entry[on], return_inverse=True)[1].ravel()   # (subdomain, edge)
        mean = np.bincount(group, weights=delta[on]) / np.bincount(group)
        out = delta.copy()
        out[on] = mean[group]
        return out

    def to_primal(self, f_W: np.ndarray) -> np.ndarray:
        """Loads in the new basis, f^ = T^T f, shape (n_W,)."""
        return f_W if self.T_W is None else self._T_W_T @ f_W

    def from_primal(self, u_W: np.ndarray) -> np.ndarray:
        """Solutions in the original basis, u = T u^, shape (n_W,)."""
        return u_W if self.T_W is None else self.T_W @ u_W
