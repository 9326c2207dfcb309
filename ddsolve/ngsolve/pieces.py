"""The disjoint pieces of a partitioned mesh, and the check that a form is not singular on one of them.

:class:`~ddsolve.ngsolve.inverse.DDInverse` treats every disjoint piece of the mesh (parts joined by a
facet or a shared vertex dof) as a body of its own, and refuses a form that annihilates the constants
on a piece with no fixed vertex dof (pure Neumann there) with one ``InputError``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import InputError

__all__ = ["check_not_singular", "mesh_pieces"]


def _mesh_pieces(part: np.ndarray, graph: tuple[np.ndarray, np.ndarray],
                 vertex_dofs: np.ndarray | None = None) -> tuple[int, np.ndarray]:
    """The disjoint pieces of the mesh: the number, and the piece of every part, shape (n_parts,).

    The connected components of the graph of the parts: two parts are joined when two of their
    elements share a facet (one pass over the facet pairs ``graph``), or a vertex dof
    (``vertex_dofs``: the vertex columns of the element table, shape (n_elements, k), given for a
    periodic space; this joins the two sides of a periodic identification, which share no facet of
    the mesh). ``part``: the connected part of every element.
    """
    first, second = graph
    n_parts = int(part.max()) + 1 if part.size else 0
    cut = part[first] != part[second]
    a, b = part[first][cut], part[second][cut]
    if vertex_dofs is not None and n_parts > 1:
        # the (dof, part) incidences, sorted: consecutive ones of one dof join their parts
        key = np.unique(vertex_dofs.astype(np.int64) * n_parts + np.repeat(part, vertex_dofs.shape[1]).reshape(
            vertex_dofs.shape))
        dof, owner = key // n_parts, key % n_parts
        same = dof[1:] == dof[:-1]
        a, b = np.concatenate([a, owner[:-1][same]]), np.concatenate([b, owner[1:][same]])
    joined = sp.csr_matrix((np.ones(a.size), (a, b)), shape=(n_parts, n_parts))
    return connected_components(joined, directed=False)


def mesh_pieces(part: np.ndarray, graph: tuple[np.ndarray, np.ndarray], vertex_dofs: np.ndarray,
                periodic: bool) -> tuple[int, np.ndarray]:
    """:func:`_mesh_pieces` joined through shared vertex dofs too, as the form couples them: parts that
    touch at a vertex only (two squares meeting at a corner) are one piece, not two bodies.

    The vertex incidences (one sort of n_elements x k entries, 0.5 s at 2M elements) are read only
    where the facets leave more than one piece, or for a periodic space.
    """
    n_pieces, piece_of_part = _mesh_pieces(part, graph)
    if n_pieces > 1 or periodic:
        n_pieces, piece_of_part = _mesh_pieces(part, graph, vertex_dofs)
    return n_pieces, piece_of_part


def check_not_singular(Ke: np.ndarray, T: np.ndarray, free: np.ndarray, nv: int, part: np.ndarray,
                        n_pieces: int, piece_of_part: np.ndarray) -> None:
    """Refuse a form that annihilates the constants on a piece of the mesh with no fixed vertex dof.

    In NGSolve's hierarchical H1 basis the constant 1 is 1 on the vertex dofs
    (``dof < nv``) and 0 on the edge, face and bubble dofs. On a connected piece of
    the mesh (:func:`_mesh_pieces`) with every vertex dof free (fixing only edge,
    face or bubble dofs, e.g. ``freedofs=fes.FreeDofs(True)``, keeps the constant)
    and A c = 0 there (a pure Neumann problem on that piece: the whole mesh, or one
    of several disjoint bodies of which only another is clamped) the constrained
    matrix is singular; the substructuring solvers would then fail in one of
    several ways (a singular coarse or projection factorization, a PCG breakdown,
    or a huge u that the final residual check of :meth:`~ddsolve.ngsolve.inverse.DDInverse.solve` flags),
    so one ``InputError`` names ``a`` instead. A c is formed only on the pieces
    whose vertex dofs are all free.

    Ke : (n_elements, n_local, n_local) element matrices (``ds`` terms added);
    T : (n_elements, n_local) element-to-dof table; free : (ndof,) bool;
    part : (n_elements,) connected part of every element.
    """
    piece = piece_of_part[part]                                   # (n_elements,)
    vertex = T < nv
    fixed = np.zeros(n_pieces, dtype=bool)
    fixed[piece[np.nonzero(vertex & ~free[T])[0]]] = True         # pieces with a fixed vertex dof
    if fixed.all():
        return
    el = np.flatnonzero(~fixed[piece])                            # the elements of the other pieces
    Ac = np.bincount(T[el].ravel(), weights=np.einsum("eij,ej->ei", Ke[el], vertex[el].astype(float)).ravel(),
                     minlength=free.size)
    dofs = T[el].ravel()
    dof_piece = np.full(free.size, -1)
    dof_piece[dofs] = np.repeat(piece[el], T.shape[1])
    scale = np.zeros(n_pieces)                                    # max |diagonal| of each piece
    np.maximum.at(scale, dof_piece[dofs], np.abs(np.einsum("eii->ei", Ke[el])).ravel())
    worst = np.zeros(n_pieces)                                    # max |A c| of each piece
    held = dof_piece >= 0
    np.maximum.at(worst, dof_piece[held], np.abs(Ac[held]))
    # a pure Neumann form leaves |A c| at rounding, <= 1e-15 of the largest diagonal entry (measured at orders
    # 1-6 in 2D, 1-3 in 3D); a reaction term eps u v adds about eps h^2 in 2D, so a threshold of 1e-10 refused
    # eps = 1e-6 on a 129k-dof P1 mesh (7e-12): 1e-13 refuses only condition numbers of about 1e13 and more
    singular = ~fixed & (worst <= 1e-13 * scale)
    if singular.any():
        where = "the mesh" if n_pieces == 1 else f"{int(singular.sum())} of {n_pieces} disjoint mesh pieces"
        raise InputError("a", f"the form is singular on {where}: no vertex dof fixed, constants in the kernel "
                              "(pure Neumann); fix dofs or add a reaction term")
