"""General scene representation: nodes, Q1 or P1 elements, subdomains and bodies.

A :class:`Scene` is the complete, method-independent description of one
problem: geometry (node coordinates and elements: Q1 quadrilaterals from the
structured generators, P1 triangles from netgen meshes), the
decomposition into bodies and subdomains (one subdomain label per element), the
coefficient rho per subdomain (constant on each subdomain, Section 2.2.1), the
Dirichlet nodes and the right-hand side. Nothing in it depends on the
structured generator: a partitioned netgen mesh fills the same fields.

Nodes on the interface between two *bodies* are duplicated (each body owns its
own copy); nodes on the interface between two subdomains of the same body are
shared. Interface classification (interior / edge / vertex) is derived from
multiplicities in :mod:`ddsolve.dd.substructure`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

def sorted_unique(values: np.ndarray, return_counts: bool = False):
    """Sorted distinct values of a 1-D integer array (and their counts).

    Sort-based; numpy's ``np.unique`` without counts takes a hash path that is
    an order of magnitude slower on millions of int64 keys. The stable sort
    (timsort) exploits the runs of structured meshes' keys (node and edge keys
    listed element by element: 10x faster than quicksort on the 1M-element
    structured scene) and costs the same as quicksort on random keys.
    """
    srt = np.sort(values, kind="stable")
    first = np.r_[True, srt[1:] != srt[:-1]] if srt.size else np.zeros(0, dtype=bool)
    uniq = srt[first]
    if not return_counts:
        return uniq
    starts = np.flatnonzero(first)
    return uniq, np.diff(np.r_[starts, srt.size])


def unique_row_labels(rows: np.ndarray) -> np.ndarray:
    """Label of each row among the distinct rows, numbered in lexicographic order.

    The ``inverse`` of ``np.unique(rows, axis=0, return_inverse=True)``, from one lexsort:
    numpy's row-wise unique sorts a structured view of the rows, measured 20x slower
    (1.5 s against 0.07 s for 1M rows of two coordinates).

    Parameters
    ----------
    rows : ndarray, shape (n, k)

    Returns
    -------
    ndarray of int64, shape (n,)
    """
    rows = np.asarray(rows)
    labels = np.empty(rows.shape[0], dtype=np.int64)
    if rows.shape[0] == 0:
        return labels
    order = np.lexsort(rows.T[::-1])                    # first column first
    ranked = rows[order]
    new = np.r_[True, np.any(ranked[1:] != ranked[:-1], axis=1)]
    labels[order] = np.cumsum(new) - 1
    return labels


def _array(name: str, value, ndim: int, width: int | None = None, integer: bool = False) -> np.ndarray:
    """``value`` as an array of ``ndim`` dimensions (and ``width`` columns), of integers or reals, else
    :class:`~ddsolve.errors.InputError` naming ``name``."""
    from ..errors import InputError

    a = np.asarray(value)
    if a.ndim != ndim or (width is not None and a.shape[1] != width):
        want = "(n,)" if ndim == 1 else f"(n, {width})"
        raise InputError(name, f"must be an array of shape {want}, got shape {a.shape}")
    if integer and a.size and a.dtype.kind not in "iu":
        raise InputError(name, f"must hold integer ids, got dtype {a.dtype}")
    if not integer and a.dtype.kind not in "biuf":
        raise InputError(name, f"must be a real array, got dtype {a.dtype}")
    return a


def _in_range(name: str, a: np.ndarray, n: int) -> None:
    """Every id of ``a`` in [0, n), else :class:`~ddsolve.errors.InputError` naming ``name``."""
    from ..errors import InputError

    if a.size and (int(a.min()) < 0 or int(a.max()) >= n):
        bad = a.min() if int(a.min()) < 0 else a.max()
        raise InputError(name, f"id {int(bad)} is out of range [0, {n})")


def check_mesh_arrays(coords, elements, width: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Node coordinates, shape (n_nodes, 2), finite, and elements, shape (n_elements, width) (width 3 or 4
    when None), of node ids in [0, n_nodes), at least one: the arrays, else
    :class:`~ddsolve.errors.InputError` naming ``coords`` or ``elements`` (what netgen reads unchecked)."""
    from ..errors import InputError

    coords = _array("coords", coords, 2, 2)
    if not np.all(np.isfinite(coords)):
        raise InputError("coords", "must be finite")
    if width is None:
        width = int(np.shape(elements)[1]) if np.ndim(elements) == 2 and np.shape(elements)[1] in (3, 4) else 3
    elements = _array("elements", elements, 2, width, integer=True)
    _in_range("elements", elements, coords.shape[0])
    if elements.shape[0] == 0:
        raise InputError("elements", "the mesh has no elements")
    return coords, elements


#: Element types: number of nodes per element -> name.
ELEMENT_TYPES = {4: "Q1", 3: "P1"}

#: A right-hand side: a number, or ``f(x, y)`` called once with NGSolve's coordinate functions ``ngsolve.x``,
#: ``ngsolve.y`` and returning a CoefficientFunction (use ``ngsolve.sin``, ``ngsolve.IfPos``: numpy's ufuncs do
#: not take CoefficientFunctions).
RightHandSide = Callable[[np.ndarray, np.ndarray], np.ndarray] | float


@dataclass
class Scene:
    """Geometry and decomposition of one problem.

    Attributes
    ----------
    coords : ndarray, shape (n_nodes, 2)
        Node coordinates.
    elements : ndarray of int, shape (n_elements, 4) or (n_elements, 3)
        Q1 quadrilaterals (counter-clockwise node ids) or P1 triangles.
    element_subdomain : ndarray of int, shape (n_elements,)
        Subdomain label of each element, 0..n_subdomains-1.
    subdomain_body : ndarray of int, shape (n_subdomains,)
        Body label of each subdomain.
    rho : ndarray, shape (n_subdomains,)
        Positive coefficient of each subdomain.
    dirichlet : ndarray of bool, shape (n_nodes,)
        True where u = 0 is imposed.
    f : float, callable or ndarray
        Right-hand side of -div(rho grad u) = f: a number, ``f(x, y)`` (called with NGSolve's coordinate
        CoefficientFunctions, see :data:`RightHandSide`), element-wise constants of shape (n_elements,),
        or (P1 scenes) the element load vectors of shape (n_elements, 3)
        (:func:`ddsolve.scene.assembly.assemble`).
    subdomain_grid : ndarray of int, shape (n_subdomains, 2), optional
        (column, row) of each subdomain in its body for structured scenes
        (used for checkerboard patterns and reporting only).
    contact_pairs : ndarray of int, shape (n_pairs, 2)
        Matching node pairs (a, b) on inter-body interfaces (empty for one body).
    element_type : {"Q1", "P1"}
        Derived from the width of ``elements`` when left empty; a given value
        must agree with it.
    """

    coords: np.ndarray
    elements: np.ndarray
    element_subdomain: np.ndarray
    subdomain_body: np.ndarray
    rho: np.ndarray
    dirichlet: np.ndarray
    f: RightHandSide = 1.0
    subdomain_grid: np.ndarray | None = None
    contact_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    element_type: str = ""
    _boundary_cache: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        width = int(np.shape(self.elements)[1]) if np.ndim(self.elements) == 2 else -1
        if width not in ELEMENT_TYPES:
            raise ValueError(f"elements must have 4 (Q1) or 3 (P1) nodes per row, got shape {np.shape(self.elements)}")
        derived = ELEMENT_TYPES[width]
        if self.element_type and self.element_type != derived:
            raise ValueError(f"element_type {self.element_type!r} does not match elements of width {width}")
        self.element_type = derived

    def check(self) -> None:
        """Refuse inconsistent arrays before anything reads them, and store each field as the ndarray the
        solvers read (a list becomes an array): one O(n) pass, :class:`InputError` naming the field (a user's
        scene with 3 columns of coordinates crashed netgen in assembly and output, an element id of -1
        corrupted memory in the VTK writer, arrays of the wrong length gave numpy's IndexError).

        Checks the shapes and dtypes of the attributes above, node ids in [0, n_nodes), subdomain labels in
        [0, n_subdomains), body labels >= 0, finite coordinates, and a load ``f`` of a valid form (finite
        where it is numbers). ``rho``'s values are checked where it is used (:func:`ddsolve.prepare`).
        """
        from ..errors import InputError, brief

        width = 4 if self.element_type == "Q1" else 3
        coords, elements = check_mesh_arrays(self.coords, self.elements, width)
        n_nodes, n_el = coords.shape[0], elements.shape[0]
        body = _array("subdomain_body", self.subdomain_body, 1, integer=True)
        n_sub = body.shape[0]
        if n_sub == 0 or int(body.min()) < 0:
            raise InputError("subdomain_body", "needs one body label >= 0 per subdomain" if n_sub else
                                               "the scene has no subdomains")
        el_sub = _array("element_subdomain", self.element_subdomain, 1, integer=True)
        if el_sub.shape[0] != n_el:
            raise InputError("element_subdomain", f"has {el_sub.shape[0]} labels for {n_el} elements")
        _in_range("element_subdomain", el_sub, n_sub)
        rho = _array("rho", self.rho, 1)
        if rho.shape[0] != n_sub:
            raise InputError("rho", f"has {rho.shape[0]} values for {n_sub} subdomains")
        dirichlet = np.asarray(self.dirichlet)
        if dirichlet.shape != (n_nodes,) or dirichlet.dtype != bool:
            raise InputError("dirichlet", f"must be a bool array of shape ({n_nodes},) (one per node), got "
                                          f"{dirichlet.dtype} of shape {dirichlet.shape}")
        pairs = np.asarray(self.contact_pairs)
        pairs = _array("contact_pairs", pairs.reshape(0, 2) if pairs.size == 0 else pairs, 2, 2, integer=True)
        _in_range("contact_pairs", pairs, n_nodes)
        grid = self.subdomain_grid
        if grid is not None:
            grid = _array("subdomain_grid", grid, 2, 2, integer=True)
            if grid.shape[0] != n_sub:
                raise InputError("subdomain_grid", f"has {grid.shape[0]} rows for {n_sub} subdomains")
        f = self.f
        if not callable(f):
            shapes = [(n_el,)] + ([(n_el, 3)] if width == 3 else [])
            number = isinstance(f, (int, float, np.integer, np.floating)) and not isinstance(f, bool)
            a = np.asarray(f) if number or isinstance(f, (np.ndarray, list, tuple)) else None
            if a is None or a.dtype.kind not in "iuf" or (a.ndim and a.shape not in shapes):
                got = (f"{a.dtype} of shape {a.shape}" if a is not None and a.dtype.kind not in "iuf" else
                       f"shape {a.shape}" if a is not None else brief(f))
                raise InputError("f", f"must be a number, a callable f(x, y) or a real array of shape "
                                      f"{' or '.join(map(str, shapes))}, got {got}")
            if not np.all(np.isfinite(a)):
                raise InputError("f", "the load must be finite")
            f = float(a) if a.ndim == 0 else a.astype(float, copy=False)
        self.coords, self.elements, self.subdomain_body, self.element_subdomain = (
            coords.astype(float, copy=False), elements, body, el_sub)
        self.rho, self.dirichlet, self.contact_pairs, self.subdomain_grid, self.f = (
            rho.astype(float, copy=False), dirichlet, pairs, grid, f)

    def locations(self) -> np.ndarray:
        """Label of each node's location, shape (n_nodes,): the body copies of one point share a label.

        Coordinates are compared after rounding to 1e-9 of the scene's extent (one lexsort,
        :func:`unique_row_labels`), as the tied interfaces of :mod:`ddsolve.multibody.interface` are found.
        """
        size = float(np.ptp(self.coords, axis=0).max()) if self.n_nodes else 1.0
        return unique_row_labels(np.round(self.coords / (size or 1.0), 9))

    def tied_dirichlet(self) -> np.ndarray:
        """The Dirichlet mask with every copy of a point Dirichlet where one body's copy is, shape (n_nodes,).

        For tied bodies (problem multibody, (4.32)): the tie u^a = u^b at a shared point carries u = 0 from
        a clamped copy to the others. The interface drops every tie that touches a Dirichlet copy, so an
        unclamped copy at that point was left free: a clamp edge of a mesh file ending at a point shared
        with another body, or the re-entrant corner of an L-shape of three bodies, was solved with u
        jumping there, 7-38% off in energy, and reported converged (a review). Not for contact, whose
        bodies are not tied.
        """
        loc = self.locations()
        dirichlet = np.asarray(self.dirichlet, dtype=bool)
        clamped = np.bincount(loc, weights=dirichlet.astype(float), minlength=int(loc.max(initial=-1)) + 1)
        return clamped[loc] > 0

    @property
    def n_nodes(self) -> int:
        return self.coords.shape[0]

    @property
    def n_subdomains(self) -> int:
        return self.subdomain_body.shape[0]

    @property
    def n_bodies(self) -> int:
        return int(self.subdomain_body.max()) + 1

    def subdomain_nodes(self) -> list[np.ndarray]:
        """Node ids of each subdomain in its canonical local order.

        The local order sorts nodes by coordinates relative to the subdomain's
        lower-left corner (row by row, ties by node id), so that geometrically
        identical subdomains list corresponding nodes in the same order; this is
        what lets them share one assembled matrix and one factorization.
        One vectorised pass over all subdomains (O(n log n)).

        Returns
        -------
        list of ndarray of int
            ``nodes[s]`` has shape (n_s,).
        """
        node_all, offsets, _ = self.subdomain_layout()
        return np.split(node_all, offsets[1:-1])

    def subdomain_layout(self, local_elements: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Flat form of :meth:`subdomain_nodes`, optionally with the local element connectivity.

        Parameters
        ----------
        local_elements : bool
            Also return each element's connectivity in local node indices of its subdomain.

        Returns
        -------
        node_all : ndarray of int, shape (sum_s n_s,)
            The canonical local node lists of all subdomains, concatenated.
        offsets : ndarray of int, shape (n_subdomains + 1,)
            Subdomain s owns ``node_all[offsets[s]:offsets[s + 1]]``.
        local : ndarray of int, shape (n_elements, width), or None
            ``node_all[offsets[element_subdomain[e]] + local[e, j]] == elements[e, j]``.
        """
        n_sub, width = self.n_subdomains, self.elements.shape[1]
        n = np.int64(self.n_nodes)
        el_sub = np.asarray(self.element_subdomain, dtype=np.int64)
        el_key = (np.repeat(el_sub, width) * n + np.asarray(self.elements, dtype=np.int64).ravel())
        key = sorted_unique(el_key)
        sub, nodes = np.divmod(key, n)
        bounds = np.searchsorted(sub, np.arange(n_sub + 1))
        xy = self.coords[nodes]
        if np.any(bounds[1:] == bounds[:-1]):
            empty = np.flatnonzero(bounds[1:] == bounds[:-1])
            raise ValueError(f"subdomains without elements: {empty[:10].tolist()}")
        lo = np.minimum.reduceat(xy, bounds[:-1], axis=0)
        hi = np.maximum.reduceat(xy, bounds[:-1], axis=0)
        scale = np.maximum((hi - lo).max(axis=1), 1e-300)
        rel = np.round((xy - lo[sub]) / scale[sub, None], 10)
        order = np.lexsort((nodes, rel[:, 0], rel[:, 1], sub))
        if not local_elements:
            return nodes[order], bounds, None
        # local index of sorted key k: its position in the canonical order minus the subdomain offset
        local_of_key = np.empty(key.size, dtype=np.int64)
        local_of_key[order] = np.arange(key.size) - bounds[sub[order]]
        local = local_of_key[np.searchsorted(key, el_key)].reshape(-1, width)
        return nodes[order], bounds, local

    def _boundary_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """(body, node) pairs on body boundaries, sorted by body, and the per-body bounds (cached)."""
        ident = (id(self.elements), id(self.element_subdomain), id(self.subdomain_body), self.n_nodes)
        if self._boundary_cache is not None and self._boundary_cache[0] == ident:
            return self._boundary_cache[1]
        els = np.asarray(self.elements, dtype=np.int64)
        width, n = els.shape[1], np.int64(self.n_nodes)
        body = np.asarray(self.subdomain_body, dtype=np.int64)[self.element_subdomain]
        a = els.ravel()
        b = np.roll(els, -1, axis=1).ravel()
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = (np.repeat(body, width) * n + lo) * n + hi
        uniq, counts = sorted_unique(key, return_counts=True)
        once = uniq[counts == 1]
        pair_body, rest = np.divmod(once, n * n)
        lo_b, hi_b = np.divmod(rest, n)
        pair_key = sorted_unique(np.concatenate([pair_body * n + lo_b, pair_body * n + hi_b]))
        pair_body, pair_node = np.divmod(pair_key, n)
        bounds = np.searchsorted(pair_body, np.arange(self.n_bodies + 1))
        result = (pair_node, bounds)
        self._boundary_cache = (ident, result)
        return result

    def boundary_nodes(self, body: int) -> np.ndarray:
        """Nodes on the boundary of one body (edges used by exactly one of its elements).

        All bodies are handled in one vectorised pass on the first call
        (O(n log n) with n the number of element edges) and cached.

        Returns
        -------
        ndarray of bool, shape (n_nodes,)
        """
        pair_node, bounds = self._boundary_pairs()
        mask = np.zeros(self.n_nodes, dtype=bool)
        mask[pair_node[bounds[body]:bounds[body + 1]]] = True
        return mask

    def boundary_node_mask(self) -> np.ndarray:
        """Nodes on the boundary of their body, all bodies at once.

        Returns
        -------
        ndarray of bool, shape (n_nodes,)
        """
        pair_node, _ = self._boundary_pairs()
        mask = np.zeros(self.n_nodes, dtype=bool)
        mask[pair_node] = True
        return mask


def triangle_areas(coords: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Areas of the triangles ``elements`` (n_elements, 3) of the points ``coords`` (n_nodes, 2), shape (n_elements,)."""
    p0, p1, p2 = (coords[elements[:, k]] for k in range(3))
    return 0.5 * np.abs((p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0]))
