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

import logging
from typing import Any

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)

#: Elements compared with ``fes.GetDofNrs`` to validate the vectorised triangle table.
CHECK_ELEMENTS = 64


def check_space(fes: Any) -> None:
    """Raise :class:`InputError` unless ``fes`` is a scalar H1 space on a 2D mesh."""
    import ngsolve

    name = type(fes).__name__
    if not isinstance(fes, ngsolve.FESpace):
        raise InputError("fes", f"expected an ngsolve H1 space, got {name}")
    if isinstance(fes, ngsolve.comp.ProductSpace):
        raise InputError("fes", f"compound or vector space {name} is not supported; give a scalar H1 space")
    if not isinstance(fes, ngsolve.H1):
        raise InputError("fes", f"space {name} ({fes.type}) is not supported; give a scalar H1 space")
    if fes.is_complex:
        raise InputError("fes", "complex H1 spaces are not supported")
    if fes.mesh.dim != 2:
        raise InputError("fes", f"only 2D meshes are supported, got a {fes.mesh.dim}D mesh")


def vertex_table(mesh: Any) -> np.ndarray:
    """Vertex numbers of each volume element (0-based), shape (n_elements, k), k = 3 or 4."""
    els = mesh.ngmesh.Elements2D().NumPy()
    nodes = np.asarray(els["nodes"], dtype=np.int64)
    nodes = nodes.reshape(nodes.shape[0], -1)
    k = nodes.shape[1]
    if k == 4 and nodes.size and (nodes[:, 3] == 0).any():
        raise InputError("mesh", "mixed triangle/quadrilateral meshes are not supported")
    return nodes[:, :k] - 1


def element_dofs(fes: Any) -> np.ndarray:
    """Global H1 dofs of every volume element in element-local order, shape (n_elements, n_local)."""
    mesh = fes.mesh
    V = vertex_table(mesh)
    if V.shape[1] == 3:
        table = _triangle_dofs(fes, V)
        if table is not None:
            return table
    return _converted_dofs(fes)


def _triangle_dofs(fes: Any, V: np.ndarray) -> np.ndarray | None:
    """Vectorised table for a uniform-order H1 space on triangles, None if NGSolve numbers differently."""
    p = int(fes.globalorder)
    ne, nv = V.shape[0], fes.mesh.nv
    if p == 1:                          # vertex dofs only: dof = vertex number
        return V.copy() if fes.ndof == nv and _matches(fes, V) else None
    edges = np.stack([np.sort(V[:, list(e)], axis=1) for e in ((2, 0), (1, 2), (0, 1))], axis=1)
    keys = (edges[:, :, 0] * nv + edges[:, :, 1]).ravel()
    uniq, edge_num = np.unique(keys, return_inverse=True)
    edge_num = edge_num.reshape(ne, 3)
    ned = uniq.size
    nb = (p - 1) * (p - 2) // 2
    if fes.ndof != nv + ned * (p - 1) + ne * nb:
        return None
    parts = [V]
    if p >= 2:
        parts.append((nv + edge_num[:, :, None] * (p - 1) + np.arange(p - 1)).reshape(ne, -1))
    if nb:
        parts.append(nv + ned * (p - 1) + np.arange(ne)[:, None] * nb + np.arange(nb))
    table = np.concatenate(parts, axis=1)
    return table if _matches(fes, table) else None


def _matches(fes: Any, table: np.ndarray) -> bool:
    """Whether ``table`` agrees with ``fes.GetDofNrs`` on CHECK_ELEMENTS elements spread over the mesh."""
    import ngsolve

    ne = table.shape[0]
    sample = np.unique(np.linspace(0, ne - 1, min(ne, CHECK_ELEMENTS)).astype(np.int64))
    for e in sample:
        if tuple(fes.GetDofNrs(ngsolve.ElementId(ngsolve.VOL, int(e)))) != tuple(table[e]):
            log.info("NGSolve dof numbering differs from the vectorised table; using ConvertOperator")
            return False
    return True


def _converted_dofs(fes: Any) -> np.ndarray:
    """Table from the 0/1 conversion matrix of fes into Discontinuous(fes) (any element shape)."""
    import ngsolve

    fesd = ngsolve.Discontinuous(fes)
    ne = fes.mesh.ne
    if ne == 0 or fesd.ndof % ne:
        raise InputError("fes", "elements with different numbers of dofs are not supported")
    C = ngsolve.comp.ConvertOperator(fes, fesd)
    r, c, v = C.COO()
    r, c, v = np.asarray(r), np.asarray(c), np.asarray(v)
    keep = np.abs(v) > 0.5
    d2h = np.full(fesd.ndof, -1, dtype=np.int64)
    d2h[r[keep]] = c[keep]
    if (d2h < 0).any():
        raise InputError("fes", "could not map the discontinuous dofs to the H1 dofs")
    return d2h.reshape(ne, -1)


def element_matrices(a: Any, fes: Any, n_local: int) -> np.ndarray:
    """Element matrices of the integrators of ``a``, shape (n_elements, n_local, n_local).

    One assembly of ``a.integrators`` on ``Discontinuous(fes)``: its matrix is
    block diagonal with one full n_local x n_local block per element, whose
    dofs are numbered contiguously in element-local order.
    """
    import ngsolve

    fesd = ngsolve.Discontinuous(fes)
    ad = ngsolve.BilinearForm(fesd, symmetric=False, check_unused=False)
    for integ in a.integrators:
        ad += integ
    ad.Assemble()
    r, c, v = ad.mat.COO()
    ne = fes.mesh.ne
    v = np.asarray(v)
    if v.size != ne * n_local * n_local:
        raise InputError("a", "unexpected sparsity of the broken element matrices")
    r = np.asarray(r)
    c = np.asarray(c)
    if not (np.all(np.diff(r) >= 0)):
        order = np.lexsort((c, r))
        v = v[order]
    return v.reshape(ne, n_local, n_local).copy()


def is_symmetric(Ke: np.ndarray, n_check: int = 32, tol: float = 1e-10) -> bool:
    """Whether a sample of element matrices equals its transpose (relative tolerance ``tol``)."""
    idx = np.unique(np.linspace(0, Ke.shape[0] - 1, min(Ke.shape[0], n_check)).astype(np.int64))
    K = Ke[idx]
    scale = np.abs(K).max(axis=(1, 2)) + 1e-300
    asym = np.abs(K - K.transpose(0, 2, 1)).max(axis=(1, 2))
    return bool(np.all(asym <= tol * scale))
