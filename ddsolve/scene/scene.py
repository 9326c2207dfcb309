"""General scene representation: nodes, Q1 elements, subdomains and bodies.

A :class:`Scene` is the complete, method-independent description of one
problem: geometry (node coordinates and quadrilateral elements), the
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

#: A right-hand side: ``f(x, y) -> values`` evaluated on arrays, or a number.
RightHandSide = Callable[[np.ndarray, np.ndarray], np.ndarray] | float


@dataclass
class Scene:
    """Geometry and decomposition of one problem.

    Attributes
    ----------
    coords : ndarray, shape (n_nodes, 2)
        Node coordinates.
    elements : ndarray of int, shape (n_elements, 4)
        Q1 quadrilaterals, counter-clockwise node ids.
    element_subdomain : ndarray of int, shape (n_elements,)
        Subdomain label of each element, 0..n_subdomains-1.
    subdomain_body : ndarray of int, shape (n_subdomains,)
        Body label of each subdomain.
    rho : ndarray, shape (n_subdomains,)
        Positive coefficient of each subdomain.
    dirichlet : ndarray of bool, shape (n_nodes,)
        True where u = 0 is imposed.
    f : float or callable
        Right-hand side of -div(rho grad u) = f (a number or ``f(x, y)``).
    subdomain_grid : ndarray of int, shape (n_subdomains, 2), optional
        (column, row) of each subdomain in its body for structured scenes
        (used for checkerboard patterns and reporting only).
    contact_pairs : ndarray of int, shape (n_pairs, 2)
        Matching node pairs (a, b) on inter-body interfaces (empty for one body).
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
        lower-left corner (row by row), so that geometrically identical
        subdomains list corresponding nodes in the same order; this is what lets
        them share one assembled matrix and one factorization.

        Returns
        -------
        list of ndarray of int
            ``nodes[s]`` has shape (n_s,).
        """
        order = np.argsort(self.element_subdomain, kind="stable")
        bounds = np.searchsorted(self.element_subdomain[order], np.arange(self.n_subdomains + 1))
        out = []
        for s in range(self.n_subdomains):
            nodes = np.unique(self.elements[order[bounds[s]:bounds[s + 1]]])
            xy = self.coords[nodes] - self.coords[nodes].min(axis=0)
            scale = max(float(np.ptp(self.coords[nodes], axis=0).max()), 1e-300)
            key = np.round(xy / scale, 10)
            out.append(nodes[np.lexsort((key[:, 0], key[:, 1]))])
        return out

    def boundary_nodes(self, body: int) -> np.ndarray:
        """Nodes on the boundary of one body (edges used by exactly one element).

        Returns
        -------
        ndarray of bool, shape (n_nodes,)
        """
        els = self.elements[self.subdomain_body[self.element_subdomain] == body]
        edges = np.concatenate([els[:, [k, (k + 1) % 4]] for k in range(4)])
        edges = np.sort(edges, axis=1)
        uniq, counts = np.unique(edges, axis=0, return_counts=True)
        mask = np.zeros(self.n_nodes, dtype=bool)
        mask[uniq[counts == 1].ravel()] = True
        return mask
