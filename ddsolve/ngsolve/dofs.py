"""Element-to-dof tables and broken element matrices of an NGSolve H1 space.

Everything here is vectorised over the elements (no Python loop over them):

* :func:`element_dofs`: the (n_elements, n_local) table of global H1 dofs of
  every volume element, in NGSolve's element-local order (vertices, edges,
  bubbles). On triangles it is built from the vertex table and NGSolve's edge
  numbering (edges sorted by their (smaller, larger) vertex pair, checked on
  a sample of elements against ``fes.GetDofNrs``); elsewhere from
  ``ngsolve.comp.ConvertOperator(fes, Discontinuous(fes))``.
* :func:`element_matrices`: the element matrices of the user's integrators,
  from one assembly of the same integrators on ``Discontinuous(fes)`` (element
  blocks on the same mesh, so coefficient functions stay valid).
"""
from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..errors import InputError
from .facets import TET_FACES

log = logging.getLogger(__name__)


@contextlib.contextmanager
def _expected_proxy_notice() -> Iterator[None]:
    """Silence NGSolve's notice "proxy not matching space, checking if it is working anyway".

    NGSolve writes it (to the C-level stderr) whenever an integrator of ``a``, made with the
    test and trial functions of ``fes``, is added to a form on another space: the broken
    space ``Discontinuous(fes)`` and the boundary-only space, which is how the element
    matrices are obtained here, by design. An integrator that does not work on them raises
    ``NgException`` (reported as an :class:`~ddsolve.errors.InputError`), so nothing is lost.
    """
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):          # no file descriptor 2 (embedded interpreters): say nothing
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)

#: Elements compared with ``fes.GetDofNrs`` to validate the vectorised triangle table.
CHECK_ELEMENTS = 64
#: NGSolve's element-local edges (pairs of local vertices) of a triangle and of a tetrahedron, in
#: the order of the element's dofs; the faces are :data:`~ddsolve.ngsolve.facets.TET_FACES` (face i
#: without vertex i).
TRIG_EDGES = ((2, 0), (1, 2), (0, 1))
TET_EDGES = ((0, 3), (1, 3), (2, 3), (0, 1), (0, 2), (1, 2))


def check_space(fes: Any) -> None:
    """Raise :class:`InputError` unless ``fes`` is a scalar H1 space on a 2D or 3D mesh."""
    import ngsolve

    name = type(fes).__name__
    if not isinstance(fes, ngsolve.FESpace):
        raise InputError("fes", f"expected an ngsolve H1 space, got {name}")
    if isinstance(fes, ngsolve.comp.ProductSpace):
        raise InputError("fes", f"compound or vector space {name} is not supported; give a scalar H1 space")
    if isinstance(fes, ngsolve.comp.Periodic) and isinstance(fes.base_space, ngsolve.H1):
        check_space(fes.base_space)     # Periodic(H1(...)): its elements read the identified dofs
        return
    if not isinstance(fes, ngsolve.H1):
        raise InputError("fes", f"space {name} ({fes.type}) is not supported; give a scalar H1 space")
    if fes.is_complex:
        raise InputError("fes", "complex H1 spaces are not supported")
    if int(getattr(fes, "dim", 1)) != 1:
        raise InputError("fes", f"vector-valued H1 (dim={fes.dim}) is not supported; give a scalar H1 space")
    if fes.mesh.dim not in (2, 3):
        raise InputError("fes", f"only 2D and 3D meshes are supported, got a {fes.mesh.dim}D mesh")


def uncompressed(fes: Any) -> tuple[Any, np.ndarray | None]:
    """The space under ``ngsolve.Compress(space)`` and the dofs of it that ``fes`` numbers.

    Returns
    -------
    space : ngsolve.FESpace
        ``fes`` itself where it is not compressed.
    dofs : ndarray of int, shape (fes.ndof,), or None
        Compressed dof i is dof ``dofs[i]`` of ``space`` (NGSolve's active dofs, in order); None
        where ``fes`` is not compressed.
    """
    import ngsolve

    if not isinstance(fes, ngsolve.comp.Compress):
        return fes, None
    space = fes.GetBaseSpace()
    if isinstance(space, ngsolve.comp.Compress):
        raise InputError("fes", "a space compressed twice is not supported; give Compress(H1(...)) once")
    # the embedding (a permutation matrix, space.ndof x fes.ndof) applied to 1..n numbers the dofs
    E = fes.Embedding()
    x = ngsolve.BaseVector(fes.ndof, False)
    x.FV().NumPy()[:] = np.arange(1, fes.ndof + 1)
    y = ngsolve.BaseVector(space.ndof, False)
    y.data = E * x
    number = np.rint(y.FV().NumPy()).astype(np.int64)
    held = np.flatnonzero(number)
    dofs = np.full(fes.ndof, -1, dtype=np.int64)
    dofs[number[held] - 1] = held
    if held.size != fes.ndof or (dofs < 0).any():
        raise InputError("fes", f"Compress: the embedding maps {held.size} of {fes.ndof} dofs (fes.Update() "
                                "after a change of the space?)")
    return space, dofs


#: netgen's 3D element types (``Elements3D().NumPy()["type"]``) and their vertices: TET, TET10, HEX, HEX20.
VERTICES_3D = {20: 4, 21: 4, 25: 8, 26: 8}


def vertex_table(mesh: Any) -> np.ndarray:
    """Vertex numbers of each volume element (0-based), shape (n_elements, k).

    2D: triangles (k = 3) or quadrilaterals (k = 4), vertices listed around the
    element. 3D: tetrahedra (k = 4) or hexahedra (k = 8, netgen's order: four around
    the bottom face, then the four above them); a mesh of other or mixed 3D element
    types raises :class:`InputError`.
    """
    if mesh.dim == 3:
        els = mesh.ngmesh.Elements3D().NumPy()
        nodes = np.asarray(els["nodes"], dtype=np.int64)
        nodes = nodes.reshape(nodes.shape[0], -1)
        # the vertices of netgen's element types: a second-order element (10-node tetrahedron, 20-node
        # hexahedron) lists its edge nodes after them (counting its nodes refused those meshes; a review)
        types = np.asarray(els["type"], dtype=np.int64)
        lookup = np.zeros(max(VERTICES_3D) + 1, dtype=np.int64)        # 0: a type not supported
        lookup[list(VERTICES_3D)] = list(VERTICES_3D.values())
        vertices = np.where((types >= 0) & (types < lookup.size), lookup[np.clip(types, 0, lookup.size - 1)], 0)
        k = int(vertices[0]) if vertices.size else 4
        if k == 0 or (vertices != k).any():
            raise InputError("mesh", "only tetrahedral or hexahedral 3D meshes are supported (prisms, pyramids "
                                     "or mixed element types found)")
        return nodes[:, :k] - 1
    els = mesh.ngmesh.Elements2D().NumPy()
    nodes = np.asarray(els["nodes"], dtype=np.int64)
    nodes = nodes.reshape(nodes.shape[0], -1)
    k = nodes.shape[1]
    if k == 4 and nodes.size and (nodes[:, 3] == 0).any():
        raise InputError("mesh", "mixed triangle/quadrilateral meshes are not supported")
    return nodes[:, :k] - 1


def element_index(mesh: Any) -> np.ndarray:
    """The material index of every volume element (netgen's ``index``, 1-based), shape (n_elements,)."""
    els = mesh.ngmesh.Elements3D() if mesh.dim == 3 else mesh.ngmesh.Elements2D()
    return np.asarray(els.NumPy()["index"], dtype=np.int64)


def active_elements(fes: Any) -> np.ndarray | None:
    """Mesh numbers of the volume elements that carry dofs of ``fes``, or None where all of them do.

    A space made with ``definedon=`` (e.g. ``H1(mesh, definedon="inner")``) has dofs on the
    elements of its regions only; NGSolve numbers the vertex dofs of the whole mesh (those
    outside unused, never free), the edge, face and cell dofs of those elements only, in the
    mesh's order.

    Returns
    -------
    ndarray of int, shape (n_active,), increasing, or None

    Raises
    ------
    InputError
        ``fes`` defined on boundaries only, or on no volume element.
    """
    import ngsolve

    mask = np.array(list(fes.GetDefinedOnRegion().Mask()), dtype=bool)     # one flag per material
    if not mask.any():   # all False: no definedon=, or definedon= boundaries (then no element has dofs)
        if fes.mesh.ne and not len(fes.GetDofNrs(ngsolve.ElementId(ngsolve.VOL, 0))):
            raise InputError("fes", "the space has no dofs on the volume elements (definedon= boundaries?); "
                                    "give a space on (some of) the mesh's materials")
        return None
    on = mask[element_index(fes.mesh) - 1]
    if on.all():
        return None
    if not on.any():
        raise InputError("fes", "the space is defined on no volume element (definedon= matches no material)")
    return np.flatnonzero(on)


def element_dofs(fes: Any, elements: np.ndarray | None = None) -> np.ndarray:
    """Global H1 dofs of volume elements in element-local order, shape (n_elements, n_local).

    ``elements``: the mesh numbers of the rows (:func:`active_elements` of a space with
    ``definedon=``); None for every element of the mesh.
    """
    import ngsolve

    mesh = fes.mesh
    V = vertex_table(mesh)
    if elements is not None:
        V = V[elements]
    if isinstance(fes, ngsolve.comp.Periodic):
        # the identified dofs differ from the vectorised table on the periodic boundary only, which the
        # sample of _matches may miss on a fine mesh: the conversion operator reads every element
        return _converted_dofs(fes, V.shape[0])
    if mesh.dim == 2 and V.shape[1] == 3:
        table = _triangle_dofs(fes, V, elements)
        if table is not None:
            return table
    elif mesh.dim == 3 and V.shape[1] == 4:
        table = _tetrahedron_dofs(fes, V, elements)
        if table is not None:
            return table
    return _converted_dofs(fes, V.shape[0])


def _triangle_dofs(fes: Any, V: np.ndarray, elements: np.ndarray | None = None) -> np.ndarray | None:
    """Vectorised table for a uniform-order H1 space on triangles, None if NGSolve numbers differently.

    ``V``: the vertex table of the elements ``elements`` (mesh numbers; None: all, in order).
    """
    p = int(fes.globalorder)
    ne, nv = V.shape[0], fes.mesh.nv
    if p == 1:                          # vertex dofs only: dof = vertex number
        return V.copy() if fes.ndof == nv and _matches(fes, V, elements) else None
    edges = np.stack([np.sort(V[:, list(e)], axis=1) for e in TRIG_EDGES], axis=1)
    keys = (edges[:, :, 0] * nv + edges[:, :, 1]).ravel()
    edge_num, ned = _numbered(keys)
    edge_num = edge_num.reshape(ne, 3)
    nb = (p - 1) * (p - 2) // 2
    if fes.ndof != nv + ned * (p - 1) + ne * nb:
        return None
    parts = [V]
    if p >= 2:
        parts.append((nv + edge_num[:, :, None] * (p - 1) + np.arange(p - 1)).reshape(ne, -1))
    if nb:
        parts.append(nv + ned * (p - 1) + np.arange(ne)[:, None] * nb + np.arange(nb))
    table = np.concatenate(parts, axis=1)
    return table if _matches(fes, table, elements) else None


def _numbered(keys: np.ndarray) -> tuple[np.ndarray, int]:
    """Rank of every key among the distinct keys (sorted), and their number."""
    uniq, number = np.unique(keys, return_inverse=True)
    return number, uniq.size


def _tetrahedron_dofs(fes: Any, V: np.ndarray, elements: np.ndarray | None = None) -> np.ndarray | None:
    """Vectorised table for a uniform-order H1 space on tetrahedra, None if NGSolve numbers differently.

    NGSolve numbers the vertex dofs first, then p - 1 dofs per edge, (p-1)(p-2)/2 per face and
    (p-1)(p-2)(p-3)/6 per cell, edges and faces in the order of their sorted vertex numbers; an
    element lists its edges as (0,3), (1,3), (2,3), (0,1), (0,2), (1,2) and its face i without
    vertex i. Checked against ``fes.GetDofNrs`` on CHECK_ELEMENTS elements (else None).
    ``V``: the vertex table of the elements ``elements`` (mesh numbers; None: all, in order).
    """
    from .facets import element_facets

    p = int(fes.globalorder)
    ne, nv = V.shape[0], fes.mesh.nv
    n = np.int64(nv)
    if p == 1:                          # vertex dofs only: dof = vertex number
        return V.copy() if fes.ndof == nv and _matches(fes, V, elements) else None
    E = np.sort(V[:, np.array(TET_EDGES)], axis=2)
    edge_num, ned = _numbered((E[:, :, 0] * n + E[:, :, 1]).ravel())
    ne_dofs, nf_dofs, nc_dofs = p - 1, (p - 1) * (p - 2) // 2, (p - 1) * (p - 2) * (p - 3) // 6
    parts = [V, (nv + edge_num.reshape(ne, 6)[:, :, None] * ne_dofs + np.arange(ne_dofs)).reshape(ne, -1)]
    nface = 0
    if nf_dofs and nv >= 2 ** 21:       # the face keys would overflow int64
        return None
    if nf_dofs:
        F = element_facets(V, 3)       # face i without vertex i, sorted
        face_num, nface = _numbered(((F[:, :, 0] * n + F[:, :, 1]) * n + F[:, :, 2]).ravel())
        parts.append((nv + ned * ne_dofs + face_num.reshape(ne, 4)[:, :, None] * nf_dofs
                      + np.arange(nf_dofs)).reshape(ne, -1))
    if nc_dofs:
        parts.append(nv + ned * ne_dofs + nface * nf_dofs + np.arange(ne)[:, None] * nc_dofs + np.arange(nc_dofs))
    table = np.concatenate(parts, axis=1)
    if fes.ndof != nv + ned * ne_dofs + nface * nf_dofs + ne * nc_dofs:
        return None
    return table if _matches(fes, table, elements) else None


def node_vertices(T: np.ndarray, order: int, dim: int, ndof: int) -> np.ndarray | None:
    """The vertex dofs of the mesh node (vertex, edge or face) that carries each H1 dof.

    Read from the element table ``T`` (NGSolve's element-local order: vertex dofs,
    ``order - 1`` per edge in :data:`TRIG_EDGES` / :data:`TET_EDGES` order, the face
    dofs of :data:`TET_FACES`, then the cell dofs). Used only to order the subdomain
    factorizations (:func:`ddsolve.dd.local._anchored_order`): a wrong answer costs fill,
    never accuracy.

    Parameters
    ----------
    T : ndarray of int, shape (n_elements, n_local)
        :func:`element_dofs` of a uniform-order H1 space on triangles or tetrahedra.
    order, dim, ndof : int

    Returns
    -------
    ndarray of int, shape (ndof, m), or None
        Row d: d itself for a vertex dof; the vertex dofs of its edge (m = 2 in 2D) or
        face (m = 3 in 3D) for an edge or face dof; -1 for cell dofs and padding.
        None for other element shapes (quadrilaterals) or an unexpected table.
    """
    p = int(order)
    k, edges, faces = (3, TRIG_EDGES, ()) if dim == 2 else (4, TET_EDGES, TET_FACES)
    n_face = (p - 1) * (p - 2) // 2 if dim == 3 else 0
    cell = (p - 1) * (p - 2) // 2 if dim == 2 else (p - 1) * (p - 2) * (p - 3) // 6
    if p < 1 or T.ndim != 2 or T.shape[1] != k + len(edges) * (p - 1) + len(faces) * n_face + cell:
        return None
    out = np.full((ndof, 2 if dim == 2 else 3), -1, dtype=np.int64)
    out[T[:, :k], 0] = T[:, :k]
    col = k
    for a, b in edges:
        dofs = T[:, col:col + p - 1]
        out[dofs, 0] = T[:, a:a + 1]
        out[dofs, 1] = T[:, b:b + 1]
        col += p - 1
    for face in faces:
        dofs = T[:, col:col + n_face]
        for i, v in enumerate(face):
            out[dofs, i] = T[:, v:v + 1]
        col += n_face
    return out


def _matches(fes: Any, table: np.ndarray, elements: np.ndarray | None = None) -> bool:
    """Whether ``table`` agrees with ``fes.GetDofNrs`` on CHECK_ELEMENTS of its rows spread over the mesh
    (row e: mesh element ``elements[e]``, or e where ``elements`` is None)."""
    import ngsolve

    ne = table.shape[0]
    sample = np.unique(np.linspace(0, ne - 1, min(ne, CHECK_ELEMENTS)).astype(np.int64))
    for e in sample:
        nr = int(e if elements is None else elements[e])
        if tuple(fes.GetDofNrs(ngsolve.ElementId(ngsolve.VOL, nr))) != tuple(table[e]):
            log.info("NGSolve dof numbering differs from the vectorised table; using ConvertOperator")
            return False
    return True


def _converted_dofs(fes: Any, ne: int | None = None) -> np.ndarray:
    """Table from the 0/1 conversion matrix of fes into Discontinuous(fes) (any element shape), for
    the ``ne`` elements with dofs (default: all of the mesh's; Discontinuous numbers them element by
    element, in the mesh's order)."""
    import ngsolve

    fesd = ngsolve.Discontinuous(fes)
    ne = fes.mesh.ne if ne is None else ne
    if ne == 0 or fesd.ndof % ne:
        raise InputError("fes", "elements with different numbers of dofs are not supported (a space with "
                                "orders varying by element)")
    C = ngsolve.comp.ConvertOperator(fes, fesd)
    r, c, v = C.COO()
    r, c, v = np.asarray(r), np.asarray(c), np.asarray(v)
    keep = np.abs(v) > 0.5
    d2h = np.full(fesd.ndof, -1, dtype=np.int64)
    d2h[r[keep]] = c[keep]
    if (d2h < 0).any():
        raise InputError("fes", "could not map the discontinuous dofs to the H1 dofs (a Periodic space whose "
                                "definedon= region holds one side of a periodic identification only? NGSolve "
                                "leaves that side's dofs unused)")
    return d2h.reshape(ne, -1)


def element_matrices(a: Any, fes: Any, n_local: int, integrators: list | None = None,
                     n_elements: int | None = None) -> np.ndarray:
    """Element matrices of the volume integrators of ``a``, shape (n_elements, n_local, n_local).

    One assembly of the integrators (default ``a.integrators``; give the
    volume ones of :func:`split_integrators` when ``a`` has ``ds`` terms) on
    ``Discontinuous(fes)``: its matrix is block diagonal with one full
    n_local x n_local block per element, whose dofs are numbered contiguously
    in element-local order. ``n_elements``: the number of elements with dofs
    (:func:`active_elements`; default all of the mesh's).
    """
    import ngsolve
    from netgen.meshing import NgException

    fesd = ngsolve.Discontinuous(fes)
    ad = ngsolve.BilinearForm(fesd, symmetric=False, check_unused=False)
    for k, integ in enumerate(a.integrators if integrators is None else integrators):
        try:
            with _expected_proxy_notice():
                ad += integ
        except NgException as exc:
            if integrators is not None and "DummyFE" in str(exc):
                # evaluated on a boundary element, which Discontinuous(fes) does not have: a ds term that
                # split_integrators found zero on every boundary element (a coefficient 0 there, or a region
                # that matches none); it adds nothing to a.mat
                log.debug("integrator %d: a ds term that is zero on every boundary element, skipped", k)
                continue
            raise InputError("a", f"integrator {k} cannot be assembled element by element on "
                                  f"Discontinuous(fes): {exc}") from None
    try:
        ad.Assemble()
    except NgException as exc:          # e.g. a skeleton (interior facet) term, which couples two elements
        if "complex" in str(exc):        # NGSolve: "real Evaluate called for complex ..." (a.Assemble() fails so too)
            raise InputError("a", "a complex coefficient on a real space: complex forms are not supported "
                                  f"({str(exc).strip()})") from None
        raise InputError("a", f"a term couples elements (dx(skeleton=True)?): not assembled element by element "
                              f"({exc})") from None
    ne = fes.mesh.ne if n_elements is None else int(n_elements)
    vals, cols, ptr = (np.asarray(x) for x in ad.mat.CSR())     # views, no copy
    width = n_local * n_local
    if vals.size != ne * width:
        raise InputError("a", "the volume (dx) terms do not give one full matrix per element (a form without a "
                              "dx term, or one defined on some materials only, is not supported)")
    # dofs of element e are e*n_local .. (e+1)*n_local - 1: every row holds its element's block, columns sorted
    expected = (np.arange(ne)[:, None, None] * n_local + np.arange(n_local)).astype(cols.dtype)
    if np.array_equal(ptr, np.arange(ne * n_local + 1) * n_local) and np.array_equal(cols.reshape(ne, n_local, n_local), np.broadcast_to(expected, (ne, n_local, n_local))):
        return vals.reshape(ne, n_local, n_local).copy()
    r, c, v = (np.asarray(x) for x in ad.mat.COO())
    order = np.lexsort((c, r))
    return v[order].reshape(ne, n_local, n_local).copy()


def is_symmetric(Ke: np.ndarray, tol: float = 1e-10, chunk: int = 4096) -> bool:
    """Whether every element matrix equals its transpose (relative tolerance ``tol`` of its largest entry).

    All of them are read, ``chunk`` elements at a time (a form that is non-symmetric on a few
    elements only, or only through a ``ds`` term added to the elements it bounds, is found too):
    one pass over ``Ke`` in cache-sized chunks (2M P1 triangles: 0.04 s).

    Parameters
    ----------
    Ke : ndarray, shape (n_elements, n_local, n_local)
    """
    rows, cols = np.triu_indices(Ke.shape[1], 1)
    diagonal = np.arange(Ke.shape[1])
    for start in range(0, Ke.shape[0], chunk):
        K = Ke[start:start + chunk]
        upper, lower = K[:, rows, cols], K[:, cols, rows]
        scale = np.maximum(np.abs(upper).max(axis=1, initial=0.0), np.abs(K[:, diagonal, diagonal]).max(axis=1))
        if np.any(np.abs(upper - lower).max(axis=1, initial=0.0) > tol * scale + 1e-300):
            return False
    return True


def split_integrators(a: Any, fes: Any) -> tuple[list, list]:
    """The volume and the boundary (``ds``) integrators of ``a``.

    NGSolve's integrator objects do not say whether they are ``dx`` or ``ds``:
    an integrator is a boundary one when its assembly on the boundary-only
    space ``H1(mesh, definedon=mesh.Boundaries(".*"))`` (no volume elements,
    so cheap) is not zero.

    Raises
    ------
    InputError
        An integrator on the co-dimension 2 or 3 regions (``DifferentialSymbol(BBND)``:
        points in 2D, edges in 3D), found the same way on spaces defined there only.
        Broken element matrices would drop it, and the solve would answer another problem.
    """
    import ngsolve

    mesh = fes.mesh
    order = int(fes.globalorder)

    def nonzero_on(space: Any, integ: Any, k: int) -> bool:
        ab = ngsolve.BilinearForm(space, check_unused=False)
        with _expected_proxy_notice():
            ab += integ
        ab.Assemble()
        values = np.asarray(ab.mat.COO()[2])
        if not np.isfinite(values).all():       # NaN > 0 is False: a NaN ds term would pass for a dx term, dropped
            raise InputError("a", f"integrator {k} has NaN or Inf entries (a coefficient that is NaN or Inf "
                                  "somewhere, or overflows)")
        return bool(values.size and np.abs(values).max() > 0)

    fb = ngsolve.H1(mesh, order=order, definedon=mesh.Boundaries(".*"))
    volume, boundary, numbers = [], [], []
    for k, integ in enumerate(a.integrators):
        if nonzero_on(fb, integ, k):
            boundary.append(integ)
            numbers.append(k)
        else:
            volume.append(integ)
    if boundary:
        # a term on the co-dimension 2 regions (points in 2D, edges in 3D; DifferentialSymbol(BBND)) or 3
        # is nonzero on the boundary-only space too; on a space defined there only, a ds term assembles to
        # zero and it does not (0.2 s per space at 1M dofs, so only for the integrators found above)
        regions = [mesh.BBoundaries] + ([mesh.BBBoundaries] if mesh.dim == 3 else [])
        for space in (ngsolve.H1(mesh, order=order, definedon=region(".*")) for region in regions):
            for k, integ in zip(numbers, boundary):
                if nonzero_on(space, integ, k):
                    raise InputError("a", f"integrator {k} lives on points or edges of the mesh "
                                          "(DifferentialSymbol(BBND) or BBBND); only dx and ds terms are supported")
    return volume, boundary


def defined_on(regions: np.ndarray, index: int) -> bool:
    """Whether an integrator whose ``GetDefinedOn()`` is ``regions`` acts on region ``index``.

    An empty array means everywhere; NGSolve's array is only as long as the largest region listed
    (``BFI("robin", definedon=[2])`` on four boundaries: length 2), and a region beyond it is not listed.
    """
    return regions.size == 0 or (index < regions.size and bool(regions[index]))


def boundary_element_matrices(fes: Any, integrators: list) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Element matrices of boundary (``ds``) integrators, or None if there are none.

    They are computed on the boundary elements of each integrator's region
    (``GetDefinedOn``); there are O(n_elements^(1/2)) of them in 2D and
    O(n_elements^(2/3)) in 3D, so the loop over them costs little next to the
    volume assembly.

    Returns
    -------
    Kb : ndarray, shape (n_b, n_lb, n_lb)
        Summed boundary element matrices, in the local order of ``fes.GetDofNrs``.
    Tb : ndarray of int, shape (n_b, n_lb)
        Their global H1 dofs.
    Vb : ndarray of int, shape (n_b, dim)
        The vertices of each boundary element (to find the volume element it bounds).
    """
    import ngsolve

    if not integrators:
        return None
    mesh = fes.mesh
    regions = [(integ, np.array(integ.GetDefinedOn(), dtype=bool)) for integ in integrators]
    mats, dofs, verts = [], [], []
    for el in mesh.Elements(ngsolve.BND):
        active = [integ for integ, on in regions if defined_on(on, el.index)]
        if not active:
            continue
        ei = ngsolve.ElementId(el)
        fe, trafo = fes.GetFE(ei), mesh.GetTrafo(ei)
        if fe.ndof == 0:        # outside the regions of a space with definedon=: no dofs, nothing assembled
            continue
        mats.append(sum(integ.CalcElementMatrix(fe, trafo).NumPy() for integ in active))
        dofs.append(fes.GetDofNrs(ei))
        verts.append([v.nr for v in el.vertices])
    if not mats:
        return None
    log.info("%d boundary integrators on %d boundary elements", len(integrators), len(mats))
    return np.asarray(mats), np.asarray(dofs, dtype=np.int64), np.asarray(verts, dtype=np.int64)


def add_boundary_matrices(Ke: np.ndarray, T: np.ndarray, V: np.ndarray, Kb: np.ndarray, Tb: np.ndarray,
                          Vb: np.ndarray, dim: int = 2) -> None:
    """Add each boundary element matrix to the element matrix of the volume element it bounds (in place).

    A = sum_e K_e + sum_b K_b with every boundary element b on a facet (edge in
    2D, face in 3D) of one volume element e(b), so adding K_b to K_e(b) keeps the
    assembled matrix and every subdomain matrix symmetric positive semidefinite.

    Parameters
    ----------
    Ke : ndarray, shape (n_elements, n_local, n_local)
    T : ndarray of int, shape (n_elements, n_local)
    V : ndarray of int, shape (n_elements, k)
    Kb, Tb, Vb : as returned by :func:`boundary_element_matrices`
    dim : int
        Dimension of the mesh (2 or 3).
    """
    from .facets import facet_owner

    parent = facet_owner(V, dim, Vb)
    hit = T[parent][:, None, :] == Tb[:, :, None]           # (n_b, n_lb, n_local)
    if not hit.any(axis=2).all():
        raise InputError("a", "boundary element dofs are not dofs of the neighbouring volume element")
    pos = hit.argmax(axis=2)
    np.add.at(Ke, (parent[:, None, None], pos[:, :, None], pos[:, None, :]), Kb)
