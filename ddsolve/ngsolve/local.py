"""Subdomains, element condensation and the LocalProblems adapter for NGSolve spaces.

The dofs of an H1 space of any order play the role of the nodes of
:class:`ddsolve.dd.Substructures`: vertex dofs shared by three or more
subdomains (or by two on the boundary of the domain) become primal, edge dofs
have multiplicity at most two. Element bubbles (dofs of a single element) are
condensed element by element before the subdomain matrices are formed:
with b the bubble and w the other positions of element e,

    S_e = K_ww - K_wb K_bb^{-1} K_bw,     u_b = K_bb^{-1} (f_b - K_bw u_w),

batched over all elements (one ``numpy.linalg.solve`` on (n_elements, n_b, n_b)).
The condensed element matrices are scattered to the parts by the element-to-dof
map (one sparse COO assembly of the block-diagonal matrix diag(A^(i))).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import InputError
from ..scene.assembly import LocalProblems, diagonal_block
from ..scene.partition import partition_elements
from ..scene.scene import sorted_unique
from .dofs import element_index
from .facets import facet_graph

log = logging.getLogger(__name__)


@dataclass
class DofScene:
    """The part of :class:`ddsolve.scene.Scene` that :class:`~ddsolve.dd.Substructures` reads.

    Nodes are the non-bubble dofs of the H1 space (compact numbering).

    Attributes
    ----------
    n_subdomains, n_nodes : int
    rho : ndarray, shape (n_subdomains,)
        Coefficient estimate per part (mean diagonal of its matrix).
    dirichlet : ndarray of bool, shape (n_nodes,)
        Nodes that are not free dofs.
    boundary : ndarray of bool, shape (n_nodes,)
        Vertex dofs on the boundary of the domain.
    """

    n_subdomains: int
    n_nodes: int
    rho: np.ndarray
    dirichlet: np.ndarray
    boundary: np.ndarray
    n_bodies: int = 1
    subdomain_body: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def boundary_nodes(self, body: int) -> np.ndarray:
        return self.boundary

    def boundary_node_mask(self) -> np.ndarray:
        """The boundary nodes of all bodies at once (as :meth:`ddsolve.scene.Scene.boundary_node_mask`)."""
        return self.boundary


def element_parts(mesh: Any, V: np.ndarray, parts: int, partition: Any, seed: int = 0,
                  graph: tuple[np.ndarray, np.ndarray] | None = None,
                  elements: np.ndarray | None = None) -> np.ndarray:
    """Part label of every element, shape (n_elements,), labels 0..n_parts-1, every part connected.

    ``partition``: None (METIS on the element graph into ``parts``), ``"coarse"``
    (METIS into ``parts`` on the coarsest mesh of a ``mesh.Refine()`` hierarchy,
    inherited by the children), ``"materials"`` (the mesh's materials), or an
    array of length ``mesh.ne``. The element graph joins elements that share a
    facet (an edge in 2D, a face in 3D); parts that are not connected through
    facets are split into their connected pieces. ``graph``: the
    :func:`~ddsolve.ngsolve.facets.facet_graph` of V, if the caller has it.
    ``elements``: the mesh numbers of the rows of ``V`` (the elements of a space
    with ``definedon=``), None for all; a partition array then labels every
    element of the mesh, the others' labels are ignored and the parts left
    without elements dropped (the labels renumbered in order).
    """
    ne, dim = V.shape[0], int(mesh.dim)
    graph = facet_graph(V, dim) if graph is None else graph
    of_space = "" if elements is None else " of the space (definedon=)"
    if partition is None:
        if isinstance(parts, bool) or not isinstance(parts, (int, np.integer)) or parts < 1:
            raise InputError("parts", f"must be a positive integer, got {parts!r}")
        if parts > ne:
            raise InputError("parts", f"{parts} parts requested but the mesh{of_space} has only {ne} elements")
        return partition_elements(V, int(parts), seed=seed, field="parts", adjacency=graph, pieces=True)
    if isinstance(partition, str) and partition == "coarse":
        return coarse_partition(mesh, V, parts, seed=seed, graph=graph, elements=elements)
    if isinstance(partition, str):
        if partition != "materials":
            raise InputError("partition", f"expected None, 'materials', 'coarse' or an array, got {partition!r}")
        index = element_index(mesh)
        _, label = np.unique(index if elements is None else index[elements], return_inverse=True)
    else:
        label = np.asarray(partition)
        n_mesh = int(mesh.ne)
        if label.ndim != 1 or label.shape[0] != n_mesh:
            raise InputError("partition", f"expected {n_mesh} element labels, got shape {label.shape}")
        if not np.issubdtype(label.dtype, np.integer) or (label.size and label.min() < 0):
            raise InputError("partition", "labels must be non-negative integers")
        if label.size and label.max() >= n_mesh:
            raise InputError("partition", f"labels must be 0..P-1 with P parts at most the {n_mesh} elements, got "
                                          f"label {int(label.max())}")
        counts = np.bincount(label)
        if (counts == 0).any():
            raise InputError("partition", f"{int((counts == 0).sum())} empty parts (labels must be 0..P-1, "
                                          f"each used)")
        if elements is not None:      # the labels of the space's elements, renumbered 0..P'-1
            _, label = np.unique(label[elements], return_inverse=True)
    return split_disconnected(V, label.astype(np.int64), graph)


def refinement_roots(mesh: Any) -> np.ndarray:
    """Coarsest ancestor of every element of a mesh refined by ``mesh.Refine()``, shape (n_elements,).

    netgen keeps the parent of each element (``parentsurfaceelements`` in 2D,
    ``parentelements`` in 3D; -1 for the elements that replaced their parent in
    place), so the ancestors are found by pointer jumping, one vectorised step
    per refinement level.
    """
    parents = mesh.ngmesh.parentelements if mesh.dim == 3 else mesh.ngmesh.parentsurfaceelements
    parent = np.asarray(parents, dtype=np.int64).reshape(-1)
    ne = mesh.ne
    if parent.size != ne:
        return np.arange(ne)
    root = np.arange(ne)
    nxt = np.where(parent >= 0, parent, root)
    while True:
        jumped = nxt[nxt]
        if np.array_equal(jumped, nxt):
            return nxt
        nxt = jumped


def coarse_partition(mesh: Any, V: np.ndarray, parts: int, seed: int = 0,
                     graph: tuple[np.ndarray, np.ndarray] | None = None,
                     elements: np.ndarray | None = None) -> np.ndarray:
    """METIS on the coarsest mesh of the refinement hierarchy; children inherit the part.

    The coarse element graph is the fine element graph contracted by the
    coarsest ancestor (no coarse mesh is rebuilt). METIS then works on the
    coarse elements only, which is much cheaper than on the refined mesh.
    ``elements``: the mesh numbers of the rows of ``V`` (None: all).
    """
    import pymetis

    root = refinement_roots(mesh)
    if elements is not None:
        root = root[elements]
    roots, coarse = np.unique(root, return_inverse=True)
    n_c = roots.size
    if n_c == V.shape[0]:
        log.info("partition 'coarse': the mesh has no mesh.Refine() hierarchy (a mesh refined by netgen's "
                 "ngmesh.Refine() keeps none); METIS on all %d elements", n_c)
    if isinstance(parts, bool) or not isinstance(parts, (int, np.integer)) or parts < 1:
        raise InputError("parts", f"must be a positive integer, got {parts!r}")
    if parts > n_c:
        raise InputError("parts", f"{parts} parts requested but the coarse mesh has only {n_c} elements")
    if parts == 1:
        return np.zeros(V.shape[0], dtype=np.int64)
    graph = facet_graph(V, int(mesh.dim)) if graph is None else graph
    first, second = graph
    a, b = coarse[first], coarse[second]
    keep = a != b
    G = sp.coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(n_c, n_c)).tocsr()
    G = ((G + G.T) > 0).astype(np.int64).tocsr()
    adjacency = pymetis.CSRAdjacency(G.indptr.astype(np.int64), G.indices.astype(np.int64))
    _, membership = pymetis.part_graph(int(parts), adjacency, options=pymetis.Options(seed=int(seed), contig=1))
    label = np.asarray(membership, dtype=np.int64)[coarse]
    counts = np.bincount(label, minlength=parts)
    if (counts == 0).any():
        raise InputError("parts", f"METIS left {int((counts == 0).sum())} of {parts} parts empty on the coarse mesh")
    return split_disconnected(V, label, graph)


def split_disconnected(V: np.ndarray, label: np.ndarray,
                       graph: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Relabel so that every part is one connected piece (facet adjacency; ``graph``: the
    :func:`~ddsolve.ngsolve.facets.facet_graph` of V, by default that of a 2D mesh)."""
    ne = V.shape[0]
    first, second = facet_graph(V, 2) if graph is None else graph
    same = label[first] == label[second]
    G = sp.coo_matrix((np.ones(int(same.sum())), (first[same], second[same])), shape=(ne, ne))
    n, comp = connected_components(G, directed=False)
    if n != label.max() + 1:
        log.info("partition: %d parts split into %d connected pieces", label.max() + 1, n)
    return comp.astype(np.int64)


@dataclass
class Condensed:
    """Element matrices with bubbles condensed.

    Attributes
    ----------
    S : ndarray, shape (n_elements, n_w, n_w)
        Condensed element matrices on the non-bubble positions ``w``.
    w, b : ndarray of int
        Non-bubble and bubble element-local positions.
    Kbb_inv : ndarray, shape (n_elements, n_b, n_b)
    E : ndarray, shape (n_elements, n_b, n_w)
        K_bb^{-1} K_bw.
    """

    S: np.ndarray
    w: np.ndarray
    b: np.ndarray
    Kbb_inv: np.ndarray | None
    E: np.ndarray | None


def condense(Ke: np.ndarray, T: np.ndarray, free: np.ndarray) -> Condensed:
    """Condense the element bubbles: positions whose dof belongs to one element only and is free."""
    n_local = T.shape[1]
    count = np.bincount(T.ravel(), minlength=free.size)
    bubble = np.array([bool(np.all(count[T[:, k]] == 1) and np.all(free[T[:, k]])) for k in range(n_local)])
    if T.shape[0] <= 1:
        bubble[:] = False
    b, w = np.flatnonzero(bubble), np.flatnonzero(~bubble)
    if b.size == 0:
        return Condensed(S=Ke, w=w, b=b, Kbb_inv=None, E=None)
    if np.array_equal(w, np.arange(w.size)):            # bubbles last (NGSolve's element order): views
        nw = w.size
        Kww, Kbb, Kbw, Kwb = Ke[:, :nw, :nw], Ke[:, nw:, nw:], Ke[:, nw:, :nw], Ke[:, :nw, nw:]
    else:
        Kww, Kbb, Kbw, Kwb = (Ke[:, r[:, None], c[None, :]] for r, c in ((w, w), (b, b), (b, w), (w, b)))
    if b.size == 1:         # one bubble (P3 triangles): elementwise, the same numbers as the batched inv/matmul
        Kbb_inv = 1.0 / Kbb
        E = Kbb_inv * Kbw
        S = Kww - Kwb * E
    else:
        Kbb_inv = np.linalg.inv(Kbb)
        E = Kbb_inv @ Kbw
        S = Kww - Kwb @ E
    return Condensed(S=S, w=w, b=b, Kbb_inv=Kbb_inv, E=E)


@dataclass
class PartMatrices:
    """Subdomain data over the skeleton (non-bubble) dofs."""

    local: LocalProblems
    node_dof: np.ndarray        # (n_nodes,) H1 dof of each node
    n_parts: int


def part_matrices(S: np.ndarray, Tw: np.ndarray, part: np.ndarray, free: np.ndarray, ndof: int,
                  boundary_dofs: np.ndarray) -> PartMatrices:
    """Scatter condensed element matrices to the parts: LocalProblems over skeleton dofs.

    Parameters
    ----------
    S : ndarray, shape (n_elements, n_w, n_w)
    Tw : ndarray of int, shape (n_elements, n_w)
        H1 dofs of the non-bubble positions.
    part : ndarray of int, shape (n_elements,)
    free : ndarray of bool, shape (ndof,)
    ndof : int
    boundary_dofs : ndarray of bool, shape (ndof,)
        Vertex dofs on the domain boundary.
    """
    n_parts = int(part.max()) + 1
    node_dof = sorted_unique(Tw.ravel())          # sort-based (numpy's hash unique is slower here)
    node_of_dof = np.full(ndof, -1, dtype=np.int64)
    node_of_dof[node_dof] = np.arange(node_dof.size)
    n_nodes = node_dof.size
    Tn = node_of_dof[Tw]
    key = (part[:, None] * n_nodes + Tn).ravel()
    uniq, broken = np.unique(key, return_inverse=True)
    broken = broken.reshape(Tn.shape)
    sub_of_broken = uniq // n_nodes
    node_of_broken = uniq % n_nodes
    sizes = np.bincount(sub_of_broken, minlength=n_parts)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    nw = Tw.shape[1]
    n_b = uniq.size
    # row of S[e, i, j]: broken[e, i]; column: broken[e, j] (32-bit where they fit: half the bytes to sort)
    broken_index = broken.astype(np.int32 if n_b < 2**31 - 1 else np.int64)
    rows = np.repeat(broken_index, nw, axis=1).ravel()
    cols = np.tile(broken_index, (1, nw)).ravel()
    A = sp.csr_matrix((S.ravel(), (rows, cols)), shape=(n_b, n_b))
    del rows, cols
    A.sum_duplicates()
    diag = A.diagonal()
    rho = np.bincount(sub_of_broken, weights=diag, minlength=n_parts) / np.maximum(sizes, 1)
    rho = np.where(rho > 0, rho, 1.0)
    blocks = [diagonal_block(A, offsets[s], offsets[s + 1], drop_zeros=False) / rho[s] for s in range(n_parts)]
    nodes = [node_of_broken[offsets[s]:offsets[s + 1]] for s in range(n_parts)]
    scene = DofScene(n_subdomains=n_parts, n_nodes=n_nodes, rho=rho, dirichlet=~free[node_dof],
                     boundary=boundary_dofs[node_dof], subdomain_body=np.zeros(n_parts, dtype=np.int64))
    local = LocalProblems(scene=scene, nodes=nodes, template=np.arange(n_parts), stiffness=blocks,
                          loads=[np.zeros(len(nd)) for nd in nodes])
    return PartMatrices(local=local, node_dof=node_dof, n_parts=n_parts)


def ordering_anchors(sub: Any, node_dof: np.ndarray, dof_vertices: np.ndarray | None) -> np.ndarray | None:
    """W entries of the vertices of each W entry's mesh node, in the same part (``Substructures.ordering_anchors``).

    Parameters
    ----------
    sub : Substructures
        Of :func:`part_matrices`' ``local`` (W sorted by part, then node).
    node_dof : ndarray of int, shape (n_nodes,)
        H1 dof of each node.
    dof_vertices : ndarray of int, shape (ndof, m), or None
        :func:`~ddsolve.ngsolve.dofs.node_vertices`.

    Returns
    -------
    ndarray of int, shape (n_W, m), or None
        -1 where the vertex is not a W entry of the part (Dirichlet); a vertex entry
        anchors to itself. None without ``dof_vertices``.
    """
    if dof_vertices is None:
        return None
    n_nodes, n_W = node_dof.size, sub.n_W
    w_key = sub.sub_of_W * np.int64(n_nodes) + sub.node_of_W
    if n_W == 0 or np.any(w_key[1:] <= w_key[:-1]):
        return None
    node_of_dof = np.full(dof_vertices.shape[0], -1, dtype=np.int64)
    node_of_dof[node_dof] = np.arange(n_nodes)
    vertices = dof_vertices[node_dof[sub.node_of_W]]                       # (n_W, m) H1 dofs
    nodes = np.where(vertices >= 0, node_of_dof[np.maximum(vertices, 0)], -1)
    key = sub.sub_of_W[:, None] * np.int64(n_nodes) + nodes
    position = np.minimum(np.searchsorted(w_key, key), n_W - 1)
    return np.where((nodes >= 0) & (w_key[position] == key), position, -1)


def interface_edge_weights(fes: Any, part: np.ndarray, V: np.ndarray | None = None,
                           T: np.ndarray | None = None, elements: np.ndarray | None = None) -> np.ndarray:
    """w_j = int over the part interface of phi_j, for every H1 dof j, shape (ndof,).

    The weights of the edge averages (:mod:`ddsolve.dd.edges`, "Weighted
    edges"): restricted to a subdomain edge E, w_j = int_E phi_j ds for the
    dofs of E (a vertex hat's trace lives on the mesh edges at its vertex,
    all of them on E; an edge shape's on its mesh edge). One linear form
    ``0.5 * chi * v * dx(element_boundary=True)`` on the elements touching
    the interface, with chi the indicator (a ``FacetFESpace`` order-0
    GridFunction) of the mesh edges between two parts (each is integrated
    from both of its elements, hence 0.5). On NGSolve's hierarchical basis
    the hats get half the lengths of their interface mesh edges, the quadratic
    edge shape -h/12 (its sign follows the edge orientation) and the higher
    ones about 0 (orthogonal to the constants along the edge; zeroed by
    :func:`ddsolve.dd.edges.find_edges`).

    Parameters
    ----------
    fes : ngsolve.H1
    part : ndarray of int, shape (n_elements,)
        Part of every element.
    V : ndarray of int, shape (n_elements, k), optional
        :func:`~ddsolve.ngsolve.dofs.vertex_table` of the mesh.
    T : ndarray of int, shape (n_elements, n_local), optional
        :func:`~ddsolve.ngsolve.dofs.element_dofs` of ``fes`` (its edge dofs give the edge numbers).
    elements : ndarray of int, optional
        The mesh numbers of the rows of ``part`` (a space with ``definedon=``); None: every element.
    """
    import ngsolve

    mesh = fes.mesh
    F = ngsolve.FacetFESpace(mesh, order=0)
    if elements is None:
        facet = mesh_edge_numbers(mesh, V, T, int(fes.globalorder))                       # (n_elements, edges per element)
    else:     # the space numbers only its own edges: the facet space's numbers of every element, restricted
        facet = mesh_edge_numbers(mesh)[elements]
    # an edge is on the interface iff the parts of its (one or two) elements differ: zero variance test
    # (exact in floating point: counts <= 2, labels < 2**26)
    owner = np.broadcast_to(part[:, None].astype(float), facet.shape).ravel()
    count = np.bincount(facet.ravel(), minlength=F.ndof)
    s1 = np.bincount(facet.ravel(), weights=owner, minlength=F.ndof)
    s2 = np.bincount(facet.ravel(), weights=owner * owner, minlength=F.ndof)
    interface = count * s2 != s1 * s1
    chi = ngsolve.GridFunction(F)
    chi.vec.FV().NumPy()[:] = interface
    touching = interface[facet].any(axis=1)
    if elements is not None:
        touching = np.zeros(mesh.ne, dtype=bool)
        touching[elements] = interface[facet].any(axis=1)
    lf = ngsolve.LinearForm(fes)
    lf += 0.5 * chi * fes.TestFunction() * ngsolve.dx(element_boundary=True,
                                                      definedonelements=ngsolve.BitArray(list(touching)))
    lf.Assemble()
    return lf.vec.FV().NumPy().copy()


def mesh_edge_numbers(mesh: Any, V: np.ndarray | None = None, T: np.ndarray | None = None,
                      order: int = 1) -> np.ndarray:
    """The ``FacetFESpace(order=0)`` dof of every edge of every volume element, shape (n_elements, k).

    That is NGSolve's edge number, counted over the edges in use: on a mesh refined by
    netgen's ``Refine()`` the mesh keeps the coarse edges (``mesh.nedge`` counts them),
    while the facet and H1 spaces number only the edges of the fine elements.

    With the element dof table ``T`` of an H1 space of uniform ``order`` >= 2
    (n_v vertex dofs, then order - 1 dofs per edge in edge order), the first
    dof d of each element edge gives (d - n_v) / (order - 1); else the ranks of
    the sorted (smaller, larger) vertex pairs. Either is checked on
    CHECK_ELEMENTS elements against the facet space's ``GetDofNrs``; failing
    both, the table comes from the conversion operator of the facet space into
    its discontinuous version (slower: 1.1 s at 2M triangles).
    """
    import ngsolve

    from .dofs import CHECK_ELEMENTS, vertex_table

    V = vertex_table(mesh) if V is None else V
    ne, k = V.shape
    sample = np.unique(np.linspace(0, ne - 1, min(ne, CHECK_ELEMENTS)).astype(np.int64))
    F = ngsolve.FacetFESpace(mesh, order=0)

    def valid(number: np.ndarray) -> bool:
        return bool(number.size == 0 or (number.min() >= 0 and number.max() < F.ndof)) and all(
            sorted(F.GetDofNrs(ngsolve.ElementId(ngsolve.VOL, int(el)))) == sorted(number[el]) for el in sample)

    if T is not None and order >= 2 and T.shape[1] >= k * order:
        first = T[:, k:k + k * (order - 1):order - 1]
        number = (first - mesh.nv) // (order - 1)
        if valid(number):
            return number
    nv = np.int64(V.max() + 1) if V.size else np.int64(1)
    pairs = np.stack([V, np.roll(V, -1, axis=1)], axis=2)
    keys = (pairs.min(axis=2) * nv + pairs.max(axis=2)).ravel()
    uniq, number = np.unique(keys, return_inverse=True)
    number = number.reshape(ne, k)
    if uniq.size == F.ndof and valid(number):
        return number
    log.info("NGSolve edge numbering differs from the sorted vertex pairs; using ConvertOperator")
    Fd = ngsolve.Discontinuous(F)
    r, c, v = (np.asarray(x) for x in ngsolve.comp.ConvertOperator(F, Fd).COO())
    keep = v > 0.5
    facet = np.full(Fd.ndof, -1, dtype=np.int64)
    facet[r[keep]] = c[keep]
    return facet.reshape(ne, -1)
