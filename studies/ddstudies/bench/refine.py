"""Total error against a 2x refined mesh, measured exactly in the energy norm.

The Q1 space V_h of a structured mesh is contained in the Q1 space V_{h/2} of
its uniform refinement: bilinear interpolation :func:`prolongation` P maps a
coarse dof vector v to the same function on the fine mesh, and
P^T A_{h/2} P = A_h (Galerkin). With u_{h/2} the fine solution, the total
error of an approximation v of the coarse problem is

    ||u_{h/2} - P v||_{A_{h/2}}^2 = E - 2 g^T v + v^T A_h v,
    E = u_{h/2}^T A_{h/2} u_{h/2},   g = P^T A_{h/2} u_{h/2},

so a :class:`FineReference` keeps only E and the coarse vector g. By Galerkin
orthogonality the square of the total error of v is (up to the error of
u_{h/2} itself) the square of the discretization error of u_h plus the
square of the algebraic error ||u_h - v||_{A_h}. Errors are relative to
||u_{h/2}||_{A_{h/2}} = sqrt(E).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from ddsolve.scene import Scene
from ddsolve.spec import ProblemSpec


def refined_spec(spec: ProblemSpec, factor: int = 2) -> ProblemSpec:
    """The same problem with ``factor`` times more elements per subdomain side."""
    return replace(spec, elements=spec.elements * int(factor))


def node_bodies(scene: Scene) -> np.ndarray:
    """Body of every node (nodes on body interfaces are duplicated per body), shape (n_nodes,)."""
    body = np.full(scene.n_nodes, -1, dtype=np.int64)
    body[scene.elements.ravel()] = np.repeat(scene.subdomain_body[scene.element_subdomain], 4)
    return body


def _grid_index(scene: Scene, h: float) -> np.ndarray:
    origin = scene.coords.min(axis=0)
    index = np.rint((scene.coords - origin) / h).astype(np.int64)
    if not np.allclose(index * h + origin, scene.coords, atol=1e-8 * h):
        raise ValueError("the scene's nodes do not lie on a grid of spacing h")
    return index


def prolongation(coarse: Scene, coarse_dof: np.ndarray, fine: Scene, fine_dof: np.ndarray) -> sp.csr_matrix:
    """Bilinear interpolation from a structured mesh to its uniform 2x refinement.

    Parameters
    ----------
    coarse, fine : Scene
        Structured Q1 meshes of the same bodies; every fine element is a
        quarter of a coarse one.
    coarse_dof, fine_dof : ndarray of int, shape (n_nodes,)
        Dof of each node, -1 on Dirichlet nodes
        (:attr:`ddsolve.dd.Substructures.dof_of_node`).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_fine_dofs, n_coarse_dofs)
        Fine node values of the coarse function (Dirichlet values are zero).

    Raises
    ------
    ValueError
        If the fine mesh is not the 2x refinement of the coarse one.
    """
    edge = np.abs(fine.coords[fine.elements[:, 1]] - fine.coords[fine.elements[:, 0]]).max(axis=1)
    h = float(edge.min())
    fine_idx = _grid_index(fine, h)
    coarse_idx = _grid_index(coarse, h)
    if np.any(coarse_idx % 2):
        raise ValueError("coarse nodes are not nodes of the refined grid")
    size = int(max(fine_idx.max(), coarse_idx.max())) + 2

    def key(body: np.ndarray, ij: np.ndarray) -> np.ndarray:
        return (body * size + ij[:, 0]) * size + ij[:, 1]

    c_key = key(node_bodies(coarse), coarse_idx)
    order = np.argsort(c_key)
    c_sorted = c_key[order]
    f_body = node_bodies(fine)
    free = np.flatnonzero(fine_dof >= 0)
    rows, cols, vals = [], [], []
    odd = fine_idx[free] % 2
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            # parent (i + dx, j + dy) exists when dx = 0 on even i and dx = +-1 on odd i
            sel = ((odd[:, 0] == 1) == (dx != 0)) & ((odd[:, 1] == 1) == (dy != 0))
            nodes = free[sel]
            target = key(f_body[nodes], fine_idx[nodes] + np.array([dx, dy]))
            pos = np.searchsorted(c_sorted, target)
            found = (pos < c_sorted.size) & (c_sorted[np.minimum(pos, c_sorted.size - 1)] == target)
            if not np.all(found):
                raise ValueError("the fine mesh is not the 2x refinement of the coarse mesh")
            parent_dof = coarse_dof[order[pos]]
            weight = 0.5 ** ((dx != 0) + (dy != 0))
            keep = parent_dof >= 0
            rows.append(fine_dof[nodes[keep]])
            cols.append(parent_dof[keep])
            vals.append(np.full(int(keep.sum()), weight))
    n_fine, n_coarse = int(fine_dof.max()) + 1, int(coarse_dof.max()) + 1
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n_fine, n_coarse))


@dataclass
class FineReference:
    """What the total error of a coarse approximation needs from the fine solution.

    Attributes
    ----------
    energy : float
        E = u_{h/2}^T A_{h/2} u_{h/2}.
    g : ndarray, shape (n_coarse_dofs,)
        P^T A_{h/2} u_{h/2}.
    """

    energy: float
    g: np.ndarray

    @classmethod
    def from_fine(cls, A_fine: sp.spmatrix, u_fine: np.ndarray, P: sp.spmatrix) -> "FineReference":
        """E and g of the fine solution ``u_fine`` (A_fine: fine energy matrix, P: :func:`prolongation`)."""
        Au = A_fine @ u_fine
        return cls(energy=float(u_fine @ Au), g=np.asarray(P.T @ Au, dtype=float))

    def total_error(self, A: sp.spmatrix, v: np.ndarray) -> float:
        """||u_{h/2} - P v||_{A_{h/2}} / ||u_{h/2}||_{A_{h/2}} for a coarse vector ``v`` (A = A_h)."""
        square = self.energy - 2.0 * float(self.g @ v) + float(v @ (A @ v))
        return math.sqrt(max(square, 0.0) / self.energy) if self.energy > 0 else math.nan
