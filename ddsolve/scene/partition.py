"""METIS partitions of element meshes into connected, non-empty subdomains.

The subdomains of an unstructured body are the parts of a METIS partition
(through ``pymetis``) of its *element graph*: elements are vertices, two
elements are adjacent when they share an edge. METIS runs with a fixed seed
and its contiguity option, so a partition is reproducible. A part that still
comes out disconnected is repaired: every connected piece but the largest is
given to the neighbouring part it shares most edges with, until every part is
one connected piece (Section 2.2.1 assumes connected subdomains; the kernel of
a floating subdomain's matrix is then exactly the constants).
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import InputError
from .scene import sorted_unique

log = logging.getLogger(__name__)

#: Seed handed to METIS (partitions are deterministic).
METIS_SEED = 0
#: At most this many repair sweeps (each sweep merges every stray piece into a neighbour).
MAX_REPAIR_SWEEPS = 20


def element_graph(elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edge-adjacency graph of the elements of one mesh.

    Parameters
    ----------
    elements : ndarray of int, shape (n_elements, k)
        Node ids of each element, nodes listed around the element (k = 3 or 4).

    Returns
    -------
    first, second : ndarray of int, shape (n_adjacent,)
        Pairs of elements sharing an edge, each pair once (first < second).
    """
    els = np.asarray(elements, dtype=np.int64)
    n_el, width = els.shape
    a, b = els.ravel(), np.roll(els, -1, axis=1).ravel()
    n = np.int64(els.max() + 1) if els.size else np.int64(1)
    key = np.minimum(a, b) * n + np.maximum(a, b)
    owner = np.repeat(np.arange(n_el, dtype=np.int64), width)
    srt = np.argsort(key, kind="stable")        # keeps netgen's runs: 2x faster than quicksort
    key, owner = key[srt], owner[srt]
    same = np.flatnonzero(key[1:] == key[:-1])
    first, second = owner[same], owner[same + 1]
    return np.minimum(first, second), np.maximum(first, second)


def _adjacency(n: int, first: np.ndarray, second: np.ndarray) -> sp.csr_matrix:
    """Symmetric adjacency matrix in canonical CSR form (sorted column indices: a reproducible METIS input)."""
    data = np.ones(2 * first.size, dtype=np.int8)
    graph = sp.csr_matrix((data, (np.r_[first, second], np.r_[second, first])), shape=(n, n))
    graph.sort_indices()
    return graph


def partition_elements(elements: np.ndarray, parts: int, *, seed: int = METIS_SEED,
                       field: str = "parts",
                       adjacency: tuple[np.ndarray, np.ndarray] | None = None,
                       pieces: bool = False) -> np.ndarray:
    """Split the elements of one connected body into ``parts`` connected subdomains.

    Parameters
    ----------
    elements : ndarray of int, shape (n_elements, k)
        Elements of one body.
    parts : int
        Number of subdomains, 1 <= parts <= n_elements.
    seed : int
        METIS seed.
    field : str
        Name used in error messages.
    adjacency : (ndarray, ndarray), optional
        The element graph of ``elements`` as pairs (e, f), e < f, in any order
        (:func:`element_graph` when None; :func:`ddsolve.scene.unstructured.split_bodies`
        hands over the one found by its own edge sort).
    pieces : bool
        A disconnected body: refused (False), or (True) each connected piece is
        partitioned on its own into a share of ``parts`` in proportion to its
        elements, at least one (so the labels may number a little more or less
        than ``parts``).

    Returns
    -------
    ndarray of int, shape (n_elements,)
        Subdomain label 0..parts-1 of each element; every label occurs and every
        subdomain is connected through element edges.

    Raises
    ------
    InputError
        ``parts`` < 1 or above the number of elements; a disconnected body (unless
        ``pieces``); a METIS partition with empty parts.
    """
    n_el = int(np.shape(elements)[0])
    if isinstance(parts, bool) or int(parts) != parts or parts < 1:
        raise InputError(field, f"must be a positive integer, got {parts!r}")
    parts = int(parts)
    if parts > n_el:
        raise InputError(field, f"{parts} subdomains requested but the body has only {n_el} elements; "
                                f"use fewer parts or a finer mesh (smaller maxh, more refine)")
    first, second = element_graph(elements) if adjacency is None else adjacency
    graph = _adjacency(n_el, first, second)
    n_comp, comp = connected_components(graph, directed=False)
    if n_comp > 1:
        if not pieces:
            raise InputError("mesh", f"a body of {n_el} elements is not connected ({n_comp} pieces); "
                                     f"give each piece its own material")
        return _partition_pieces(elements, parts, comp, n_comp, first, second, seed=seed, field=field)
    if parts == 1:
        return np.zeros(n_el, dtype=np.int64)
    import pymetis

    adjacency = pymetis.CSRAdjacency(graph.indptr.astype(np.int64), graph.indices.astype(np.int64))
    options = pymetis.Options(seed=int(seed), contig=1)
    _, membership = pymetis.part_graph(parts, adjacency, options=options)
    label = np.asarray(membership, dtype=np.int64)
    label = repair_partition(label, first, second, parts, graph=graph)
    counts = np.bincount(label, minlength=parts)
    if np.any(counts == 0):
        raise InputError(field, f"METIS left {int(np.sum(counts == 0))} of {parts} subdomains empty on a body of "
                                f"{n_el} elements; use fewer parts or a finer mesh")
    return label


def _partition_pieces(elements: np.ndarray, parts: int, comp: np.ndarray, n_comp: int, first: np.ndarray,
                      second: np.ndarray, *, seed: int, field: str) -> np.ndarray:
    """:func:`partition_elements` of every connected piece (``comp``: piece of each element) on its own.

    Piece k gets max(1, round(parts n_k / n)) parts (at most its n_k elements); the pairs are
    sorted by piece once, so the cost is one METIS call per piece with more than one part.
    """
    n_el = comp.size
    size = np.bincount(comp, minlength=n_comp)
    share = np.minimum(np.maximum(1, np.rint(parts * size / n_el).astype(np.int64)), size)
    offset = np.concatenate([[0], np.cumsum(share)])
    label = offset[comp].astype(np.int64)                  # pieces of one part: their offset
    position = np.zeros(n_el, dtype=np.int64)              # index of an element within its piece
    by_piece = np.argsort(comp, kind="stable")
    starts = np.concatenate([[0], np.cumsum(size)])
    position[by_piece] = np.arange(n_el) - np.repeat(starts[:-1], size)
    pair_piece = comp[first]
    pair_order = np.argsort(pair_piece, kind="stable")
    pair_bounds = np.searchsorted(pair_piece[pair_order], np.arange(n_comp + 1))
    for k in np.flatnonzero(share > 1):
        members = by_piece[starts[k]:starts[k + 1]]
        pairs = pair_order[pair_bounds[k]:pair_bounds[k + 1]]
        sub = partition_elements(elements[members], int(share[k]), seed=seed, field=field,
                                 adjacency=(position[first[pairs]], position[second[pairs]]))
        label[members] += sub
    return label


def repair_partition(label: np.ndarray, first: np.ndarray, second: np.ndarray, parts: int, *,
                     graph: sp.csr_matrix | None = None) -> np.ndarray:
    """Make every part connected: merge stray pieces into a neighbouring part.

    Parameters
    ----------
    label : ndarray of int, shape (n_elements,)
        Part of each element.
    first, second : ndarray of int
        Element adjacency pairs (:func:`element_graph`).
    parts : int
    graph : csr_matrix, optional
        The adjacency matrix of the pairs (:func:`_adjacency`), if already
        built: the graph inside the parts is then read off its entries instead
        of being built again.

    Returns
    -------
    ndarray of int, shape (n_elements,)
        Labels in which each part is one connected piece (the largest piece of
        each part keeps its label; every other piece joins the adjacent part
        with which it shares the most element edges). Vectorised: one
        connected-components pass per sweep.
    """
    label = np.asarray(label, dtype=np.int64).copy()
    n_el = label.size
    for sweep in range(MAX_REPAIR_SWEEPS):
        inner = label[first] == label[second]
        n_comp, comp = connected_components(_inner_graph(n_el, first, second, inner, label, graph),
                                            directed=False)
        comp_part = np.zeros(n_comp, dtype=np.int64)
        comp_part[comp] = label
        size = np.bincount(comp, minlength=n_comp)
        # largest piece of each part (ties: lowest component id)
        order = np.lexsort((np.arange(n_comp), -size, comp_part))
        is_main = np.zeros(n_comp, dtype=bool)
        is_main[order[np.r_[True, comp_part[order][1:] != comp_part[order][:-1]]]] = True
        stray = ~is_main
        if not stray.any():
            return label
        # edges from stray pieces to other parts, counted per (piece, part)
        cross = ~inner
        ca = np.r_[comp[first[cross]], comp[second[cross]]]
        pb = np.r_[label[second[cross]], label[first[cross]]]
        keep = stray[ca]
        key, counts = sorted_unique(ca[keep] * parts + pb[keep], return_counts=True)
        piece, target = np.divmod(key, parts)
        best = np.lexsort((target, -counts, piece))
        first_of_piece = best[np.r_[True, piece[best][1:] != piece[best][:-1]]]
        new_part = comp_part.copy()
        new_part[piece[first_of_piece]] = target[first_of_piece]
        log.debug("partition repair sweep %d: %d stray pieces", sweep, int(stray.sum()))
        label = new_part[comp]
    raise InputError("parts", f"could not make every subdomain connected in {MAX_REPAIR_SWEEPS} sweeps")


def _inner_graph(n: int, first: np.ndarray, second: np.ndarray, inner: np.ndarray, label: np.ndarray,
                 graph: sp.csr_matrix | None) -> sp.csr_matrix:
    """Adjacency of the pairs inside one part: the entries of ``graph`` (canonical CSR) joining equal labels.

    Equal, array for array, to ``_adjacency(n, first[inner], second[inner])``
    (same entries, sorted column indices), without its sort.
    """
    if graph is None:
        return _adjacency(n, first[inner], second[inner])
    rows = np.repeat(np.arange(n), np.diff(graph.indptr))
    keep = label[rows] == label[graph.indices]
    indptr = np.r_[0, np.cumsum(np.bincount(rows[keep], minlength=n))]
    return sp.csr_matrix((graph.data[keep], graph.indices[keep], indptr), shape=(n, n))


def is_connected_partition(elements: np.ndarray, label: np.ndarray) -> bool:
    """True when every part of ``label`` is one connected piece of the element graph."""
    first, second = element_graph(elements)
    inner = label[first] == label[second]
    n_comp, _ = connected_components(_adjacency(label.size, first[inner], second[inner]), directed=False)
    return n_comp == np.unique(label).size
