"""Direct reference for the equality-constrained multibody problem.

min 1/2 u^T A u - f^T u  subject to  u_a = u_b for every active global pair,
with A the block-diagonal (over bodies) assembled stiffness; floating bodies
make A singular. The constraints are eliminated exactly by merging the dofs
they identify (connected components of the constraint graph): u = T v, and
T^T A T v = T^T f is SPD once every floating body is tied to a clamped one.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla

from ..dd.common import MethodOutput
from ..dd.substructure import Substructures
from .interface import GlobalInterface


def merge_matrix(sub: Substructures, gi: GlobalInterface, active: np.ndarray) -> sp.csr_matrix:
    """T, shape (ndof, n_merged): columns are the classes of dofs tied by active constraints."""
    dofs = sub.dof_of_node[gi.pair_nodes[active]]
    graph = sp.csr_matrix((np.ones(len(dofs)), (dofs[:, 0], dofs[:, 1])), shape=(sub.ndof, sub.ndof))
    n_comp, label = csgraph.connected_components(graph, directed=False)
    return sp.csr_matrix((np.ones(sub.ndof), (np.arange(sub.ndof), label)), shape=(sub.ndof, n_comp))


def solve_constrained_direct(sub: Substructures, gi: GlobalInterface, active: np.ndarray) -> MethodOutput:
    """Sparse direct solve of the equality-constrained multibody problem.

    Returns
    -------
    MethodOutput
        ``u`` has shape (ndof,), one value per body copy of each node.

    Raises
    ------
    ValueError
        If a floating body is not tied to a clamped body by active constraints.
    """
    T = merge_matrix(sub, gi, active)
    A = (T.T @ sub.global_matrix() @ T).tocsc()
    f = T.T @ sub.assemble_vector(sub.f_W)
    lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    if np.any(np.abs(lu.U.diagonal()) < 1e-12 * abs(A.diagonal()).max()):
        raise ValueError("a floating body is not tied to a clamped body by the active constraints")
    return MethodOutput(u=T @ lu.solve(f), krylov=None, nlambda=0, n_factorizations=1)
