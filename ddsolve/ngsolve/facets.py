"""Facets of the volume elements of a 2D or 3D mesh: adjacency, boundary vertices, lookup.

A *facet* is an edge of a triangle or quadrilateral (2D), a triangular face
of a tetrahedron or a quadrilateral face of a hexahedron (3D). Everything is
vectorised over the elements:

* :func:`element_facets`: the vertices of every facet of every element;
* :func:`facet_graph`: pairs of elements sharing a facet (the element graph
  that METIS partitions, and in which a part must be connected);
* :func:`boundary_vertices`: vertices on facets of one element only (the
  boundary of the domain);
* :func:`facet_owner`: the volume element and facet of each given facet (a
  boundary element of a ``ds`` integrator).

In 2D :func:`facet_graph` is :func:`ddsolve.scene.partition.element_graph`
itself, so 2D partitions are those of the structured and unstructured scenes.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..scene.partition import element_graph

__all__ = ["boundary_vertices", "element_facets", "facet_adjacency", "facet_graph", "facet_owner"]

#: The faces of a tetrahedron (vertex positions), each the vertices but one.
TET_FACES = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))
#: The faces of a hexahedron in netgen's vertex order (0-3 around the bottom, 4-7 above them).
HEX_FACES = ((0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7))


def element_facets(V: np.ndarray, dim: int) -> np.ndarray:
    """Vertices of the facets of every element, each facet's vertices sorted.

    Parameters
    ----------
    V : ndarray of int, shape (n_elements, k)
        Vertex table (:func:`~ddsolve.ngsolve.dofs.vertex_table`): k = 3 or 4 in
        2D (listed around the element), k = 4 (tetrahedra) or 8 (hexahedra) in 3D.
    dim : int
        2 or 3.

    Returns
    -------
    ndarray of int, shape (n_elements, n_facets, m)
        2D: n_facets = k, m = 2 (edge i joins vertices i and i + 1); tetrahedra:
        n_facets = 4, m = 3 (face i omits vertex i); hexahedra: n_facets = 6, m = 4
        (:data:`HEX_FACES`).
    """
    V = np.asarray(V, dtype=np.int64)
    if dim == 2:
        F = np.stack([V, np.roll(V, -1, axis=1)], axis=2)
    elif dim == 3:
        F = V[:, np.array(HEX_FACES if V.shape[1] == 8 else TET_FACES)]
    else:
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    return np.sort(F, axis=2)


def _sorted_rows(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Order of the rows of F (n, m), sorted within each row, so that equal rows are adjacent, and
    whether each row in that order equals the next.

    Rows are encoded as one int64 key (m = 2 or 3 numbers below 2^21 each: meshes of up to
    about two million vertices) and sorted by one stable argsort (it keeps the runs of a
    netgen mesh: 0.50 s against 0.70 s for quicksort on 6.1M faces of a refined tetrahedral
    mesh, 0.75 s against 1.07 s on 3M triangle edges); larger meshes use ``np.lexsort``
    (about 4x slower).
    """
    n = int(F.max()) + 1 if F.size else 1
    if n ** F.shape[1] < 2 ** 63:
        key = F[:, 0].astype(np.int64)
        for j in range(1, F.shape[1]):
            key = key * n + F[:, j]
        order = np.argsort(key, kind="stable")
        key = key[order]
        return order, key[1:] == key[:-1]
    order = np.lexsort(F.T[::-1])
    Fs = F[order]
    return order, np.all(Fs[1:] == Fs[:-1], axis=1)


def facet_adjacency(V: np.ndarray, dim: int, n: int) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
    """:func:`facet_graph` and :func:`boundary_vertices` from one sort of the facets.

    In 2D the pairs are those of :func:`~ddsolve.scene.partition.element_graph` (elements sharing
    an edge), from the same sort as the boundary vertices (two sorts before: 2.0 s against 0.75 s
    for 2M triangles).
    """
    F = element_facets(V, dim)
    F = F.reshape(-1, F.shape[-1])
    order, same = _sorted_rows(F)
    at = np.flatnonzero(same)
    owner = order // (F.shape[0] // max(V.shape[0], 1))
    a, b = owner[at], owner[at + 1]
    return (np.minimum(a, b), np.maximum(a, b)), _single_facet_vertices(F, order, at, n)


def _single_facet_vertices(F: np.ndarray, order: np.ndarray, at: np.ndarray, n: int) -> np.ndarray:
    """Mask (n,) of the vertices of the facets that occur once (``at``: where row order[k] equals the next)."""
    single = np.ones(F.shape[0], dtype=bool)
    single[at] = False
    single[at + 1] = False
    out = np.zeros(n, dtype=bool)
    out[F[order][single].ravel()] = True
    return out


def facet_graph(V: np.ndarray, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (e, f), e < f, of elements sharing a facet, each pair once.

    Returns
    -------
    first, second : ndarray of int, shape (n_pairs,)
    """
    if dim == 2:
        return element_graph(V)
    return facet_adjacency(V, dim, int(V.max()) + 1 if V.size else 0)[0]


def boundary_vertices(V: np.ndarray, dim: int, n: int) -> np.ndarray:
    """Vertices on a facet of exactly one element, as a mask of shape (n,)."""
    F = element_facets(V, dim)
    F = F.reshape(-1, F.shape[-1])
    order, same = _sorted_rows(F)
    return _single_facet_vertices(F, order, np.flatnonzero(same), n)


def facet_owner(V: np.ndarray, dim: int, facets: np.ndarray) -> np.ndarray:
    """The element of every given facet, shape (n_given,).

    Parameters
    ----------
    facets : ndarray of int, shape (n_given, m)
        Vertices of facets of the mesh (e.g. of boundary elements), in any order; m as in
        :func:`element_facets`.

    Raises
    ------
    InputError
        A given facet is no facet of any element.
    """
    F = element_facets(V, dim)
    F = F.reshape(-1, F.shape[-1])
    n_f = F.shape[0] // max(V.shape[0], 1)
    G = np.sort(np.asarray(facets, dtype=np.int64), axis=1)
    both = np.concatenate([F, G])
    order = np.lexsort(both.T[::-1])
    is_given = order >= F.shape[0]
    # each given facet sorts right after the element facets equal to it (lexsort is stable)
    rows = both[order]
    last_elem = np.maximum.accumulate(np.where(~is_given, np.arange(order.size), -1))
    pos = np.flatnonzero(is_given)
    src = last_elem[pos]
    ok = src >= 0
    ok[ok] = np.all(rows[src[ok]] == rows[pos[ok]], axis=1)
    if not ok.all():
        raise InputError("a", "a boundary element does not lie on a facet of a volume element")
    result = np.empty(G.shape[0], dtype=np.int64)
    result[order[pos] - F.shape[0]] = order[src] // n_f
    return result
