"""The spaces and per-active-set objects of the hybrid method (Section 4.2 of Lee (2009)).

:class:`InterfaceSpace` is a space of per-body continuous nodal values on a set of W entries
(u_Gamma, the global interface Gamma_OL, the local interface Gamma_0), with its scatter to and
gather from W; :class:`ActiveSet` holds what one active set Z^k defines (jump operators,
G^k = Z B^ R_c and the projection P^k). :class:`~ddsolve.multibody.hybrid.HybridSolver` builds
and uses both.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..dd.operators import PairJump
from ..dd.projection import Projection
from ..dd.substructure import Substructures

__all__ = ["ActiveSet", "InterfaceSpace"]


class InterfaceSpace:
    """A space of continuous (per body) nodal values on a subset of W entries.

    Parameters
    ----------
    sub : Substructures
    mask : ndarray of bool, shape (n_W,)
        W entries carrying the space; all subdomain copies of a node belong to
        one compact index (their common global dof).

    Attributes
    ----------
    idx : ndarray of int, shape (n_entries,)
        W positions of the entries.
    pos : ndarray of int, shape (n_entries,)
        Compact index (0..n-1) of each entry.
    dofs : ndarray of int, shape (n,)
        Global dof of each compact index (sorted).
    n : int
        Dimension of the space.
    key : tuple
        Cache key (index bytes) of the operators built on the space.
    """

    def __init__(self, sub: Substructures, mask: np.ndarray) -> None:
        self.n_W = sub.n_W
        self.idx = np.flatnonzero(mask)
        self.dofs = np.unique(sub.l2g[self.idx])
        self.pos = np.searchsorted(self.dofs, sub.l2g[self.idx])
        self.n = int(self.dofs.size)
        #: cache key of the space for the operators handed out on it (its index bytes)
        self.key = (self.idx.tobytes(), self.pos.tobytes(), self.n)

    def scatter(self, v: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        """W vector holding v (times ``weights`` of the entries) on every copy, zero elsewhere."""
        w = np.zeros(self.n_W)
        w[self.idx] = v[self.pos] if weights is None else weights * v[self.pos]
        return w

    def gather(self, w: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        """Sum of the copies (times ``weights``) of a W vector, shape (n,)."""
        vals = w[self.idx] if weights is None else weights * w[self.idx]
        return np.bincount(self.pos, weights=vals, minlength=self.n)


@dataclass
class ActiveSet:
    """Objects of one active set Z^k (no factorizations): jump operators, G^k and its projection.

    Attributes
    ----------
    active : ndarray of bool, shape (n_gl,)
        The diagonal of Z^k.
    jump : PairJump, shape (n_act, n_gamma)
        Z B^_{Gamma,c}: (B u)_k = u_a - u_b on the u_Gamma copies a, b of active pair k.
    scaled_jump_gamma : PairJump, shape (n_act, n_gamma)
        Z B^_{Gamma,c,D}: the entry of copy a multiplied by the body weight of b and vice versa.
    scaled_jump_global : PairJump, shape (n_act, n_GL)
        Z B_{Gamma_OL,D}: the same on the global-interface space (the entries of (4.11)).
    G : sparse matrix, shape (n_act, n_float)
        G^k = Z B^ R_c.
    projection : Projection
        P^k = I - G^k (G^kT G^k)^{-1} G^kT (Section 4.2); the identity without floating bodies.
    weighted : dict
        Q-weighted projections by kind (``"dirichlet"``, ``"lumped"``), built on demand.
    """

    active: np.ndarray
    jump: PairJump
    scaled_jump_gamma: PairJump
    scaled_jump_global: PairJump
    G: sp.csr_matrix
    projection: Projection
    weighted: dict = field(default_factory=dict)

    @property
    def n_active(self) -> int:
        """Number of active multipliers."""
        return int(self.jump.first.size)
