"""Unstructured scenes: netgen meshes of P1 triangles split into METIS subdomains.

Every problem is meshed as ONE netgen (OCC) geometry whose bodies are its
materials, so interfaces between bodies are conforming: the meshes of two
bodies have the same nodes on their common edge. The mesh is then split apart,
each body getting its own copy of the interface nodes (as in the structured
scenes of :mod:`ddsolve.scene.structured`), and every body is partitioned into
``parts`` connected subdomains by METIS (:mod:`ddsolve.scene.partition`).

Geometries
----------
poisson
    ``square`` (unit square, default), ``lshape`` ((0,1)^2 without
    [1/2,1]x[1/2,1]), ``hole`` ((0,1)^2 without the disc of radius 1/4 about
    (1/2,1/2)); u = 0 on the whole boundary.
multibody
    Problem (4.32): the unit square split into ``bodies`` x ``bodies`` square
    bodies (body b = by * bodies + bx as in :func:`structured_square`), tied on
    the inter-body interfaces; u = 0 on the outer boundary.
contact
    The two membranes of (3.1): Omega^1 = (0,1)^2 clamped on x = 0 and
    Omega^2 = (1,2)x(0,1) floating; the contact line x = 1 gives node-to-node
    pairs. The load-patch edges y = 3/4 (Omega^1) and y = 1/4 (Omega^2) are
    mesh lines, so the default Dostal loads are integrated exactly.

A user's mesh is read by :func:`scene_from_mesh` (materials are bodies, named
boundaries carry Dirichlet conditions and the contact interface).
"""
from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Sequence

import numpy as np

from ..errors import InputError
from ..options import GEOMETRIES  # geometries of each problem (the first is the default)
from .contact import DOSTAL_LOADS, check_contact_load, dostal_loads
from .partition import partition_elements
from .scene import RightHandSide, Scene, sorted_unique, triangle_areas
from .volfile import load_netgen_mesh  # noqa: F401 - re-exported (ddsolve.scene.unstructured.load_netgen_mesh)

log = logging.getLogger(__name__)

#: Timings (seconds) of the last :func:`unstructured_scene` / :func:`scene_from_mesh` call:
#: ``"mesh"`` (netgen meshing and refinement), ``"split"`` and ``"partition"``.
LAST_TIMINGS: dict[str, float] = {}


@dataclass
class NetgenData:
    """Arrays of a 2-D netgen mesh (0-based ids).

    Attributes
    ----------
    coords : ndarray, shape (n_nodes, 2)
    elements : ndarray of int, shape (n_elements, 3)
    material : ndarray of int, shape (n_elements,)
        0-based material index of each element; names in ``material_names``.
    segments : ndarray of int, shape (n_segments, 2)
        Boundary and interface segments.
    segment_bc : ndarray of int, shape (n_segments,)
        0-based boundary-condition index; names in ``bc_names``.
    """

    coords: np.ndarray
    elements: np.ndarray
    material: np.ndarray
    segments: np.ndarray
    segment_bc: np.ndarray
    material_names: list[str] = field(default_factory=list)
    bc_names: list[str] = field(default_factory=list)


def netgen_arrays(ngmesh: Any) -> NetgenData:
    """Read coordinates, triangles and segments of a netgen mesh with bulk numpy calls.

    Raises
    ------
    InputError
        ``mesh``: not a 2-D mesh, no points, no elements, or elements other than triangles.
    """
    if ngmesh.dim != 2:
        raise InputError("mesh", f"need a 2-D netgen mesh, got dimension {ngmesh.dim}")
    if len(ngmesh.Points()) == 0:        # (Coordinates() of no points raises a ValueError of the buffer protocol)
        raise InputError("mesh", "the mesh has no points")
    # a copy: Coordinates() is a view of the mesh's memory, freed with the mesh (NetgenData may outlive it)
    coords = np.array(ngmesh.Coordinates(), dtype=float)[:, :2]
    el = ngmesh.Elements2D().NumPy()
    if el.shape[0] == 0:
        raise InputError("mesh", "the mesh has no 2-D elements")
    nodes = np.asarray(el["nodes"], dtype=np.int64)
    if nodes.shape[1] > 3 and np.any(nodes[:, 3:] > 0):
        raise InputError("mesh", "only triangular (P1) meshes are supported; the mesh has quadrilaterals "
                                 "or curved elements")
    seg = ngmesh.Elements1D().NumPy()
    segments = np.asarray(seg["nodes"], dtype=np.int64)[:, :2] - 1 if seg.shape[0] else np.zeros((0, 2), np.int64)
    segment_bc = np.asarray(seg["index"], dtype=np.int64) - 1 if seg.shape[0] else np.zeros(0, np.int64)
    material = np.asarray(el["index"], dtype=np.int64) - 1
    n_mat = int(material.max()) + 1
    n_bc = int(segment_bc.max()) + 1 if segment_bc.size else 0
    try:
        material_names = [ngmesh.GetMaterial(i + 1) for i in range(n_mat)]
        bc_names = [ngmesh.GetBCName(i) for i in range(n_bc)]
    except UnicodeDecodeError:
        raise InputError("mesh", "a material or boundary name of the mesh is not UTF-8 text") from None
    return NetgenData(coords=coords, elements=nodes[:, :3] - 1, material=material, segments=segments,
                      segment_bc=segment_bc, material_names=material_names, bc_names=bc_names)


# --------------------------------------------------------------------------- geometries
def _geometry(problem: str, geometry: str, bodies: int) -> Any:
    """OCC geometry of a problem: faces named ``body<k>``, edges ``clamp`` and ``contact`` (contact only)."""
    from netgen.occ import Circle, Glue, MoveTo, OCCGeometry

    if problem == "poisson":
        face = MoveTo(0, 0).Rectangle(1, 1).Face()
        if geometry == "lshape":
            face = face - MoveTo(0.5, 0.5).Rectangle(0.5, 0.5).Face()
        elif geometry == "hole":
            face = face - Circle((0.5, 0.5), 0.25).Face()
        face.faces.name = "body0"
        return OCCGeometry(face, dim=2)
    if problem == "multibody":
        side = 1.0 / bodies
        faces = []
        for by in range(bodies):
            for bx in range(bodies):
                f = MoveTo(bx * side, by * side).Rectangle(side, side).Face()
                f.faces.name = f"body{by * bodies + bx}"
                faces.append(f)
        return OCCGeometry(Glue(faces), dim=2)
    # contact: the two membranes of (3.1), load-patch edges as mesh lines
    low1 = MoveTo(0, 0).Rectangle(1, 0.75).Face()
    top1 = MoveTo(0, 0.75).Rectangle(1, 0.25).Face()
    low2 = MoveTo(1, 0).Rectangle(1, 0.25).Face()
    top2 = MoveTo(1, 0.25).Rectangle(1, 0.75).Face()
    for f in (low1, top1):
        f.faces.name = "body0"
    for f in (low2, top2):
        f.faces.name = "body1"
    shape = Glue([low1, top1, low2, top2])
    for edge in shape.edges:           # name edges after gluing (the glue splits and renames them)
        x = edge.center.x
        if abs(x) < 1e-9:
            edge.name = "clamp"
        elif abs(x - 1.0) < 1e-9:
            edge.name = "contact"
    return OCCGeometry(shape, dim=2)


def _check_positive(name: str, value: Any, integer: bool = False, allow_zero: bool = False) -> None:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
        and np.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if ok and integer:
        ok = int(value) == value
    if not ok:
        kind = "non-negative integer" if allow_zero else ("positive integer" if integer else "positive number")
        raise InputError(name, f"must be a {kind}, got {value!r}")


def mesh_geometry(problem: str = "poisson", *, geometry: str | None = None, maxh: float = 0.1,
                  refine: int = 0, bodies: int = 1) -> Any:
    """Mesh a built-in geometry with netgen and refine it uniformly.

    Parameters
    ----------
    problem : {"poisson", "multibody", "contact"}
    geometry : str, optional
        One of :data:`GEOMETRIES` ``[problem]`` (default: the first).
    maxh : float
        Largest element size handed to netgen.
    refine : int
        Uniform refinements after meshing (each quarters every triangle).
    bodies : int
        Bodies per side (multibody only; 1 otherwise).

    Returns
    -------
    netgen.meshing.Mesh
    """
    if problem not in GEOMETRIES:
        raise InputError("problem", f"unknown problem {problem!r}; choose one of {sorted(GEOMETRIES)}")
    geometry = GEOMETRIES[problem][0] if geometry is None else geometry
    if geometry not in GEOMETRIES[problem]:
        raise InputError("geometry", f"unknown geometry {geometry!r} for problem {problem!r}; "
                                     f"choose one of {list(GEOMETRIES[problem])}")
    _check_positive("maxh", maxh)
    _check_positive("refine", refine, integer=True, allow_zero=True)
    _check_positive("bodies", bodies, integer=True)
    if problem != "multibody" and bodies != 1:
        raise InputError("bodies", f"problem {problem!r} has fixed bodies; 'bodies' applies to multibody only")
    ngmesh = _geometry(problem, geometry, int(bodies)).GenerateMesh(maxh=float(maxh))
    for _ in range(int(refine)):
        ngmesh.Refine()
    return ngmesh


# --------------------------------------------------------------------------- splitting
def _edge_keys(elements: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edge keys lo * n + hi of all element edges, with their endpoints (lo, hi)."""
    a, b = elements.ravel(), np.roll(elements, -1, axis=1).ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return lo * n + hi, lo, hi


#: The node copies of the bodies are numbered through a dense marker array of n_bodies * n_nodes
#: entries (O(n), no sort) when it has at most this many entries per element-node slot; else by a sort.
DENSE_COPY_FACTOR = 8


class SplitMesh(NamedTuple):
    """Result of :func:`split_bodies`: the bodies' own node copies and their couplings.

    Attributes
    ----------
    coords : ndarray, shape (n_copies, 2)
    elements : ndarray of int, shape (n_elements, 3)
        In copy ids (element order unchanged).
    element_body : ndarray of int, shape (n_elements,)
    dirichlet : ndarray of bool, shape (n_copies,)
    pairs : ndarray of int, shape (n_pairs, 2)
        Copies (a, b) of one mesh node, body(a) < body(b), sorted by
        (body(a), body(b), y, x).
    adjacent : (ndarray, ndarray) of int, each shape (n_adjacent,)
        Pairs (e, f), e < f, of elements of one body sharing an edge, in no
        particular order: the element graph of :func:`ddsolve.scene.partition.element_graph`
        of every body, found by the same edge sort.
    """

    coords: np.ndarray
    elements: np.ndarray
    element_body: np.ndarray
    dirichlet: np.ndarray
    pairs: np.ndarray
    adjacent: tuple[np.ndarray, np.ndarray]


def _node_copies(slot_key: np.ndarray, n_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """Distinct keys body * n + node (sorted) and the index of each slot's key among them."""
    if n_keys <= DENSE_COPY_FACTOR * max(slot_key.size, 1):     # O(n): mark the used keys, number them
        used = np.zeros(n_keys, dtype=bool)
        used[slot_key] = True
        copy_key = np.flatnonzero(used)
        number = np.empty(n_keys, dtype=np.int64)
        number[copy_key] = np.arange(copy_key.size, dtype=np.int64)
        return copy_key, number[slot_key]
    srt = np.argsort(slot_key, kind="stable")                   # many bodies: one sort
    sorted_key = slot_key[srt]
    first = np.r_[True, sorted_key[1:] != sorted_key[:-1]]
    index = np.empty(slot_key.size, dtype=np.int64)
    index[srt] = np.cumsum(first) - 1
    return sorted_key[first], index


def split_bodies(data: NetgenData, body_of_material: np.ndarray, *, dirichlet: str | Sequence[str] = "boundary",
                 contact: str | None = None) -> SplitMesh:
    """Give every body its own copy of its nodes and find the inter-body node pairs.

    Parameters
    ----------
    data : NetgenData
    body_of_material : ndarray of int, shape (n_materials,)
        Body of each material.
    dirichlet : "boundary" or sequence of str
        ``"boundary"``: u = 0 on every edge of exactly one element (the outer
        boundary of the union of the bodies); else the names of the netgen
        boundaries on which u = 0.
    contact : str, optional
        Name of the contact boundary: its segments must be conforming
        interface edges between two bodies and they alone give the pairs;
        None: every interface edge gives pairs.

    Returns
    -------
    SplitMesh
        Node copies, elements in copy ids, Dirichlet mask, inter-body pairs
        and the element adjacency of each body.

    Notes
    -----
    One sort of the element edges (stable: it keeps the runs of netgen's
    numbering, measured 2.2x faster than quicksort on 6.6M keys) gives the
    interface pairs, the boundary edges and the element graph used by METIS;
    the node copies are numbered without a sort (:func:`_node_copies`).
    """
    n = np.int64(data.coords.shape[0])
    els = data.elements
    el_body = np.asarray(body_of_material, dtype=np.int64)[data.material]
    width = els.shape[1]
    ebody = np.repeat(el_body, width)
    n_bodies = int(el_body.max()) + 1 if el_body.size else 1
    copy_key, new_els = _node_copies(ebody * n + els.ravel(), n_bodies * int(n))
    new_els = new_els.reshape(els.shape)
    copy_node = copy_key % n

    def copy_of(body: np.ndarray, node: np.ndarray) -> np.ndarray:
        return np.searchsorted(copy_key, body * n + node)

    key, lo, hi = _edge_keys(els, n)
    srt = np.argsort(key, kind="stable")
    skey = key[srt]
    dup = np.flatnonzero(skey[1:] == skey[:-1])
    shared_a, shared_b = srt[dup], srt[dup + 1]          # element-edge slots sharing an edge
    inter = ebody[shared_a] != ebody[shared_b]
    ia, ib = shared_a[inter], shared_b[inter]
    ea, eb = shared_a[~inter] // width, shared_b[~inter] // width
    adjacent = (np.minimum(ea, eb), np.maximum(ea, eb))

    # Dirichlet edges
    if isinstance(dirichlet, str) and dirichlet == "boundary":
        single = np.ones(key.size, dtype=bool)
        single[shared_a] = False
        single[shared_b] = False
        dir_slot = np.flatnonzero(single)
    else:
        names = [dirichlet] if isinstance(dirichlet, str) else list(dirichlet)
        ids = [i for name in names for i in _bc_index(data, name, "dirichlet")]
        seg = data.segments[np.isin(data.segment_bc, ids)]
        seg_key = np.minimum(seg[:, 0], seg[:, 1]) * n + np.maximum(seg[:, 0], seg[:, 1])
        dir_slot = np.flatnonzero(np.isin(key, seg_key))
    dirichlet_mask = np.zeros(copy_key.size, dtype=bool)
    dirichlet_mask[copy_of(ebody[dir_slot], lo[dir_slot])] = True
    dirichlet_mask[copy_of(ebody[dir_slot], hi[dir_slot])] = True
    if dirichlet_mask.all():
        raise InputError("dirichlet", f"every node of the mesh lies on the Dirichlet boundary {dirichlet!r}: "
                                      f"no unknowns are left (refine the mesh: --maxh or --refine)")

    if contact is not None:
        cid = _bc_index(data, contact, "contact")
        seg = data.segments[np.isin(data.segment_bc, cid)]
        seg_key = sorted_unique(np.minimum(seg[:, 0], seg[:, 1]) * n + np.maximum(seg[:, 0], seg[:, 1]))
        found = np.isin(seg_key, key[ia])
        if not found.all():
            k = seg_key[np.flatnonzero(~found)[0]]
            p, q = np.divmod(k, n)
            mid = 0.5 * (data.coords[p] + data.coords[q])
            raise InputError("contact", f"boundary {contact!r} is not a conforming interface between two bodies "
                                        f"near ({mid[0]:.6g}, {mid[1]:.6g}): {int((~found).sum())} of "
                                        f"{seg_key.size} segments belong to one body only (mesh the bodies as "
                                        f"one geometry so that their nodes match on the contact line)")
        on = np.isin(key[ia], seg_key)
        if not on.all():           # the pairs of the contact problem are every location the bodies share
            k = np.flatnonzero(~on)[0]
            mid = 0.5 * (data.coords[lo[ia[k]]] + data.coords[hi[ia[k]]])
            raise InputError("contact", f"the bodies share {int((~on).sum())} edges off {contact!r}, e.g. near "
                                        f"({mid[0]:.6g}, {mid[1]:.6g}): their whole interface must be the contact "
                                        f"boundary")
        ia, ib = ia[on], ib[on]
    single = np.ones(key.size, dtype=bool)
    single[shared_a] = False
    single[shared_b] = False
    _check_conforming(data.coords, lo[single], hi[single])
    ba, bb = ebody[ia], ebody[ib]
    b1, b2 = np.minimum(ba, bb), np.maximum(ba, bb)
    nodes = np.r_[lo[ia], hi[ia]]
    b1, b2 = np.r_[b1, b1], np.r_[b2, b2]
    pair_key = sorted_unique((b1 * n + b2) * n + nodes) if nodes.size else np.zeros(0, np.int64)
    rest, node = np.divmod(pair_key, n)
    p1, p2 = np.divmod(rest, n)
    pairs = np.stack([copy_of(p1, node), copy_of(p2, node)], axis=1) if node.size else np.zeros((0, 2), np.int64)
    if pairs.size:
        xy = data.coords[node]
        pairs = pairs[np.lexsort((xy[:, 0], xy[:, 1], p2, p1))]
    return SplitMesh(data.coords[copy_node], new_els, el_body, dirichlet_mask, pairs, adjacent)


def _check_conforming(coords: np.ndarray, a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> None:
    """Refuse a mesh in which a node of a boundary edge lies on another boundary edge.

    ``a``, ``b``: the end nodes of the edges of exactly one element. In a conforming mesh they
    form the outer boundary and meet only at shared nodes. A node inside another such edge (a
    hanging node), or on top of another node with another number, means elements that do not
    share their nodes: two bodies meshed apart along their common side, which would be tied at
    their coincident corners only and answer another problem.

    Candidates: the boundary nodes within half an edge's length of its midpoint. The edges are
    grouped by the power of two of their length, and each group is one k-d tree query with the
    radius of its longest edge (at most twice each edge's own), so a strongly graded boundary
    costs what a uniform one does: O(m log m) for m boundary edges in a mesh of non-overlapping
    edges. (One radius for all edges, half the longest, made a cluster of 4,000 short edges
    beside one long edge cost 4.9 s, and 16,000 of them ran out of memory.)
    """
    from scipy.spatial import cKDTree

    if a.size == 0:
        return
    pa, pb = coords[a], coords[b]
    d = pb - pa
    length2 = np.einsum("ij,ij->i", d, d)
    nodes = sorted_unique(np.r_[a, b])
    node_tree = cKDTree(coords[nodes])
    mid = 0.5 * (pa + pb)
    # half length < 2**e: group by e (a zero-length edge: radius of the smallest double, coincident nodes)
    _, exponent = np.frexp(np.maximum(0.5 * np.sqrt(length2), np.finfo(float).tiny))
    order = np.argsort(exponent, kind="stable")
    bounds = np.flatnonzero(np.diff(exponent[order])) + 1
    found_i, found_j = [], []
    for group in np.split(order, bounds):
        radius = float(np.ldexp(1.0, int(exponent[group[0]]))) * (1.0 + 1e-6)
        near = node_tree.sparse_distance_matrix(cKDTree(mid[group]), radius, output_type="ndarray")
        found_i.append(near["i"])
        found_j.append(group[near["j"]])
    i, j = np.concatenate(found_i), np.concatenate(found_j)
    keep = (nodes[i] != a[j]) & (nodes[i] != b[j])
    i, j = i[keep], j[keep]
    p = coords[nodes[i]]
    t = np.einsum("ij,ij->i", p - pa[j], d[j]) / np.maximum(length2[j], 1e-300)
    gap = p - (pa[j] + t[:, None] * d[j])
    on = (np.einsum("ij,ij->i", gap, gap) <= tol ** 2 * length2[j]) & (t > -tol) & (t < 1 + tol)
    if on.any():
        x, y = p[np.flatnonzero(on)[0]]
        count = int(np.unique(nodes[i[on]]).size)
        raise InputError("mesh", f"the mesh is not conforming near ({x:.6g}, {y:.6g}): {count} boundary node(s) "
                                 "lie on another boundary edge (hanging nodes, or bodies meshed apart)")


def _bc_index(data: NetgenData, name: str, field_name: str) -> list[int]:
    """All boundary indices named ``name`` (netgen may give one name several indices)."""
    if name not in data.bc_names:
        raise InputError(field_name, f"the mesh has no boundary named {name!r}; it has {sorted(set(data.bc_names))}")
    return [i for i, bc in enumerate(data.bc_names) if bc == name]


# --------------------------------------------------------------------------- scenes
def _assemble_scene(data: NetgenData, body_of_material: np.ndarray, *, parts: int, dirichlet: Any,
                    contact: str | None, rho: float | np.ndarray, f: RightHandSide | np.ndarray,
                    seed: int) -> Scene:
    t0 = time.perf_counter()
    coords, elements, el_body, dir_mask, pairs, (adj_a, adj_b) = split_bodies(
        data, body_of_material, dirichlet=dirichlet, contact=contact)
    t1 = time.perf_counter()
    n_bodies = int(el_body.max()) + 1
    if np.any(np.bincount(el_body, minlength=n_bodies) == 0):
        raise InputError("bodies", "every body needs at least one element")
    _check_areas(coords, elements)
    element_subdomain = np.empty(elements.shape[0], dtype=np.int64)
    if n_bodies == 1:
        order, bounds = np.arange(elements.shape[0]), np.array([0, elements.shape[0]])
    else:
        order = np.argsort(el_body, kind="stable")
        bounds = np.searchsorted(el_body[order], np.arange(n_bodies + 1))
    local = np.empty(elements.shape[0], dtype=np.int64)       # index of each element within its body
    local[order] = np.arange(elements.shape[0]) - bounds[el_body[order]]
    adj_body = el_body[adj_a]
    adj_order = np.argsort(adj_body, kind="stable") if n_bodies > 1 else slice(None)
    adj_bounds = np.searchsorted(adj_body[adj_order], np.arange(n_bodies + 1))
    adj_a, adj_b = local[adj_a[adj_order]], local[adj_b[adj_order]]
    for b in range(n_bodies):                      # a loop over bodies, each touching its own elements
        members = order[bounds[b]:bounds[b + 1]]
        lo, hi = adj_bounds[b], adj_bounds[b + 1]
        element_subdomain[members] = partition_elements(elements[members], parts, seed=seed,
                                                        adjacency=(adj_a[lo:hi], adj_b[lo:hi])) + b * int(parts)
    t2 = time.perf_counter()
    LAST_TIMINGS.update(split=t1 - t0, partition=t2 - t1)
    n_sub = n_bodies * int(parts)
    try:
        rho_arr = np.broadcast_to(np.asarray(rho, dtype=float), (n_sub,)).copy()
    except (TypeError, ValueError):
        rho_arr = None
    if rho_arr is None or np.any(~np.isfinite(rho_arr)) or np.any(rho_arr <= 0):
        raise InputError("rho", f"must be positive: a number or one value per subdomain ({n_sub})")
    if isinstance(f, np.ndarray) and f.shape != (elements.shape[0],):
        raise InputError("f", f"an array load needs one value per element ({elements.shape[0]}), got {f.shape}")
    if contact is not None and pairs.size and dir_mask[pairs].any(axis=1).all():
        raise InputError("dirichlet", f"every node pair of the contact boundary {contact!r} is a Dirichlet node: "
                                      "no contact condition is left")
    one_sided = np.flatnonzero(dir_mask[pairs].sum(axis=1) == 1) if contact is not None and pairs.size else []
    if len(one_sided):             # u^1 = 0 would leave the bound u^2 >= 0, a row with one entry: not supported
        x, y = coords[pairs[one_sided[0], 0]]
        raise InputError("dirichlet", f"{len(one_sided)} contact vertices are clamped in one body only, e.g. "
                                      f"({x:.6g}, {y:.6g}): clamp both bodies there or neither")
    log.info("unstructured scene: %d nodes, %d triangles, %d bodies x %d parts, %d pairs",
             coords.shape[0], elements.shape[0], n_bodies, parts, pairs.shape[0])
    return Scene(coords=coords, elements=elements.astype(np.int64), element_subdomain=element_subdomain,
                 subdomain_body=np.repeat(np.arange(n_bodies), int(parts)), rho=rho_arr, dirichlet=dir_mask,
                 f=f, contact_pairs=pairs)


def _check_areas(coords: np.ndarray, elements: np.ndarray, tol: float = 1e-12) -> None:
    """Refuse a mesh with a degenerate triangle (area at most ``tol`` times the mean area): its element
    matrix is singular or infinite, and every solver would fail in its own way."""
    areas = triangle_areas(coords, elements)
    bad = np.flatnonzero(~(areas > tol * areas.mean())) if areas.size else areas
    if bad.size:
        x, y = coords[elements[bad[0]]].mean(axis=0)
        raise InputError("mesh", f"{bad.size} degenerate triangle(s) of zero area, the first near ({x:.6g}, {y:.6g})")


def unstructured_scene(problem: str = "poisson", *, geometry: str | None = None, maxh: float = 0.1,
                       refine: int = 0, parts: int = 4, bodies: int = 1, rho: float | np.ndarray = 1.0,
                       f: RightHandSide | np.ndarray | None = None,
                       patches: tuple[float, float] = DOSTAL_LOADS, seed: int = 0) -> Scene:
    """P1 scene of a built-in netgen geometry, each body split into ``parts`` METIS subdomains.

    Parameters
    ----------
    problem : {"poisson", "multibody", "contact"}
    geometry : str, optional
        poisson: ``"square"`` (default), ``"lshape"``, ``"hole"``;
        multibody: ``"square"``; contact: ``"membranes"``.
    maxh : float
        netgen's largest element size (h before refinement).
    refine : int
        Uniform refinements after meshing (h / 2^refine, 4^refine times the triangles).
    parts : int
        METIS subdomains per body (1 <= parts <= elements of a body).
    bodies : int
        multibody: bodies per side N_b of problem (4.32) (N_b^2 bodies).
    rho : float or ndarray, shape (n_bodies * parts,)
        Coefficient per subdomain (subdomain = body * parts + part).
    f : float, callable or ndarray of shape (n_elements,), optional
        Right-hand side (default 1; contact: the Dostal patch loads ``patches``).
    patches : (float, float)
        Contact loads on (0,1)x[3/4,1) and (1,2)x(0,1/4) when ``f`` is None.
    seed : int
        METIS seed.

    Returns
    -------
    Scene
        P1 triangles; ``element_type == "P1"``; no ``subdomain_grid``;
        ``contact_pairs`` lists the node copies on inter-body interfaces
        (contact: ordered by y, a on Omega^1).

    Raises
    ------
    InputError
        Bad problem, geometry, maxh, refine, parts, bodies, rho or f; a contact
        load that does not press Omega^2 onto Omega^1.
    """
    t0 = time.perf_counter()
    ngmesh = mesh_geometry(problem, geometry=geometry, maxh=maxh, refine=refine, bodies=bodies)
    t1 = time.perf_counter()
    data = netgen_arrays(ngmesh)
    names = data.material_names
    body_of_material = np.array([int(name[4:]) for name in names], dtype=np.int64)
    if problem == "contact":
        scene = _assemble_scene(data, body_of_material, parts=parts, dirichlet=["clamp"], contact="contact",
                                rho=rho, f=1.0 if f is None else f, seed=seed)
        centroids = scene.coords[scene.elements].mean(axis=1)
        loads = dostal_loads(centroids, *patches) if f is None else f
        if not isinstance(loads, np.ndarray) and not callable(loads):
            loads = np.full(scene.elements.shape[0], float(loads))
        if isinstance(loads, np.ndarray):
            check_contact_load(scene, loads)
        scene.f = loads
    else:
        scene = _assemble_scene(data, body_of_material, parts=parts, dirichlet="boundary", contact=None,
                                rho=rho, f=1.0 if f is None else f, seed=seed)
    LAST_TIMINGS["mesh"] = t1 - t0
    log.info("unstructured %s/%s: mesh %.3fs split %.3fs partition %.3fs", problem, geometry, t1 - t0,
             LAST_TIMINGS["split"], LAST_TIMINGS["partition"])
    return scene


def scene_from_mesh(path_or_mesh: str | os.PathLike | Any, *, bodies: Sequence[str] | None = None,
                    dirichlet: str | Sequence[str] = "boundary", contact: str | None = None, parts: int = 4,
                    refine: int = 0, rho: float | np.ndarray = 1.0, f: RightHandSide | np.ndarray = 1.0,
                    seed: int = 0, one_body: bool = False) -> Scene:
    """P1 scene of a user's netgen mesh: materials are bodies, named boundaries carry the conditions.

    Parameters
    ----------
    path_or_mesh : path or netgen.meshing.Mesh
        A 2-D netgen mesh file (``.vol``, ``.vol.gz``) or mesh.
    bodies : sequence of str, optional
        Material names in body order; several domains may share a material
        name (one body). Default: every material, in order of first index.
    dirichlet : "boundary" or str or sequence of str
        ``"boundary"``: u = 0 on the whole outer boundary; else the names of
        the boundaries where u = 0.
    contact : str, optional
        Name of the contact boundary between two bodies (must be conforming:
        the bodies share their nodes there in the mesh file).
    parts : int
        METIS subdomains per body.
    refine : int
        Uniform refinements before splitting.
    rho, f, seed
        As in :func:`unstructured_scene`.
    one_body : bool
        Every material (of ``bodies``) in one body: a problem of one domain (poisson) on a mesh of
        several materials.

    Returns
    -------
    Scene

    Raises
    ------
    InputError
        Missing or unreadable file, not a netgen mesh, an unknown material or
        boundary name, a non-conforming contact interface (with its location).
    """
    t0 = time.perf_counter()
    _check_positive("refine", refine, integer=True, allow_zero=True)
    if isinstance(path_or_mesh, (str, os.PathLike)):     # the geometry part only where Refine() needs it
        ngmesh = load_netgen_mesh(path_or_mesh, geometry=int(refine) > 0)
    else:   # Refine() works in place: refine a copy, never the caller's mesh
        ngmesh = path_or_mesh.Copy() if int(refine) > 0 else path_or_mesh
    for _ in range(int(refine)):
        ngmesh.Refine()
    data = netgen_arrays(ngmesh)
    names = data.material_names
    if bodies is None:
        order: list[str] = []
        for name in names:
            if name not in order:
                order.append(name)
        bodies = order
    bodies = list(bodies)
    twice = [b for i, b in enumerate(bodies) if b in bodies[:i]]
    if twice:           # index() took the first: m1,m2,m1 was 2 bodies (a review)
        raise InputError("bodies", f"material {twice[0]!r} is listed twice: each material is one body")
    missing = [b for b in bodies if b not in names]
    if missing:
        raise InputError("bodies", f"the mesh has no material named {missing[0]!r}; it has {sorted(set(names))}")
    used = set(np.unique(data.material).tolist())
    unassigned = sorted({names[i] for i in used} - set(bodies))
    if unassigned:
        raise InputError("bodies", f"materials {unassigned} are in the mesh but not listed as bodies")
    body_of_material = np.array([bodies.index(name) if name in bodies else -1 for name in names], dtype=np.int64)
    if one_body:
        body_of_material[body_of_material >= 0] = 0
    t1 = time.perf_counter()
    scene = _assemble_scene(data, body_of_material, parts=parts, dirichlet=dirichlet, contact=contact,
                            rho=rho, f=f, seed=seed)
    LAST_TIMINGS["mesh"] = t1 - t0
    return scene
