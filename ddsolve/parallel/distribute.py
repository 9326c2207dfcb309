"""Distribution of the subdomains over MPI ranks: the rank-local substructures.

Ownership. Subdomains are the unit: rank r owns the contiguous block
``owned_range(n_sub, P, r)`` of subdomain numbers (on a METIS scene the
subdomains of a body are its METIS parts, numbered part by part).

What every rank holds.

* The *topology* (:func:`topology`): node lists, interface classification
  (multiplicity, cross points, primal vertices completed by
  :meth:`Substructures._anchor_floating`), the delta-dagger weights and the
  global numbering of multipliers / interface dofs. This is integer metadata
  derived from the global mesh, which every rank reads (the input is a global
  mesh); it is computed redundantly at setup, with no communication.
* Its own :class:`RankSubstructures`: a :class:`~ddsolve.dd.Substructures`
  restricted to the owned subdomains, assembled by NGSolve on the owned part of
  the mesh only (:func:`owned_scene`), with the owned W entries (the W layout is
  subdomain by subdomain, so they are one contiguous slice of the global W).
  Every float array of the solve (matrices, factorizations, loads, iterates)
  is rank-local.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..dd.substructure import Substructures
from ..scene.scene import Scene

__all__ = ["owned_range", "rank_of_subdomain", "topology", "owned_scene", "RankSubstructures"]


def owned_range(n_sub: int, size: int, rank: int) -> tuple[int, int]:
    """Subdomains [lo, hi) of ``rank`` among ``size`` ranks (contiguous, balanced)."""
    return (rank * n_sub) // size, ((rank + 1) * n_sub) // size


def rank_of_subdomain(n_sub: int, size: int) -> np.ndarray:
    """Owning rank of every subdomain, shape (n_sub,)."""
    out = np.empty(n_sub, dtype=np.int64)
    for r in range(size):
        lo, hi = owned_range(n_sub, size, r)
        out[lo:hi] = r
    return out


def topology(scene: Scene, scaling: str = "rho", gamma: float = 1.0) -> Substructures:
    """The layout and interface classification of :class:`Substructures` without any assembly.

    Returns a :class:`Substructures` object with every attribute of its
    constructor except ``K_W``, ``f_W``, ``stiffness`` and ``local``
    (:meth:`Substructures._layout`, the code of the serial constructor: the same W
    order, primal vertices and delta weights as a serial solve).
    """
    topo = Substructures.__new__(Substructures)
    topo.scene = scene
    topo.n_sub = scene.n_subdomains
    topo._layout(scene, scene.subdomain_nodes(), "vertices")
    topo.scaling = scaling
    topo.gamma = float(gamma)
    topo.delta = topo.scaling_weights(scaling, gamma)
    return topo


def owned_scene(scene: Scene, lo: int, hi: int) -> Scene:
    """The scene restricted to subdomains [lo, hi) (renumbered from 0), global node ids kept."""
    el = (scene.element_subdomain >= lo) & (scene.element_subdomain < hi)
    f = scene.f
    if isinstance(f, np.ndarray):
        f = np.asarray(f)[el]
    grid = None if scene.subdomain_grid is None else scene.subdomain_grid[lo:hi]
    return replace(scene, elements=scene.elements[el], element_subdomain=scene.element_subdomain[el] - lo,
                   subdomain_body=scene.subdomain_body[lo:hi], rho=np.asarray(scene.rho)[lo:hi], f=f,
                   subdomain_grid=grid, contact_pairs=np.zeros((0, 2), dtype=np.int64))


class RankSubstructures(Substructures):
    """:class:`Substructures` of one rank's subdomains [lo, hi), classified globally.

    Built by :meth:`build` (not by the parent constructor): the layout arrays
    are the slice ``w0:w1`` of the global ``topo``'s, ``sub_of_W`` counts from
    0 at ``lo``, ``l2g`` keeps the global dof numbers, and ``K_W``, ``f_W``,
    ``stiffness`` come from the local NGSolve assembly. The serial operators
    (:class:`~ddsolve.dd.operators.DirichletSchur`,
    :class:`~ddsolve.dd.local.BatchedSolver`) act on it unchanged.

    Attributes (beyond the parent's)
    --------------------------------
    lo, hi : int
        Owned subdomains.
    w0, w1 : int
        Owned slice of the global W.
    """

    lo: int
    hi: int
    w0: int
    w1: int

    @classmethod
    def build(cls, topo: Substructures, local, lo: int, hi: int, templates: bool = True) -> "RankSubstructures":
        """``local``: the :class:`~ddsolve.scene.LocalProblems` of :func:`owned_scene` (subdomains lo..hi-1);
        ``templates`` as for :class:`Substructures` (False: every subdomain distinct, batched factorizations)."""
        self = cls.__new__(cls)
        w0, w1 = int(topo.offsets[lo]), int(topo.offsets[hi])
        self.lo, self.hi, self.w0, self.w1 = lo, hi, w0, w1
        self.local = local
        self.scene = local.scene
        self.n_sub = hi - lo
        self.templates = bool(templates)
        if templates:
            self.template = local.template
            self.stiffness = local.stiffness
            self.batch_local = None
        else:                               # as Substructures(..., templates=False)
            self.template = np.arange(hi - lo)
            self.stiffness = [local.stiffness[t] for t in local.template]
            self.batch_local = True
        self.rho = topo.rho[lo:hi]
        self.body_of_sub = topo.body_of_sub[lo:hi]
        sl = slice(w0, w1)
        self.node_of_W = topo.node_of_W[sl]
        self.sub_of_W = topo.sub_of_W[sl] - lo
        self.local_index = topo.local_index[sl]
        self.n_W = w1 - w0
        self.offsets = topo.offsets[lo:hi + 1] - w0
        self.floating_sub = topo.floating_sub[lo:hi]
        self.dof_of_node = topo.dof_of_node
        self.ndof = topo.ndof
        self.l2g = topo.l2g[sl]
        self.multiplicity = topo.multiplicity[sl]
        self.interface = topo.interface[sl]
        self.cross_point = topo.cross_point[sl]
        self.vertex = topo.vertex[sl]
        self.primal = topo.primal
        self.scaling, self.gamma = topo.scaling, topo.gamma
        self.delta = topo.delta[sl]
        nodes = local.nodes
        sizes_full = np.array([len(nd) for nd in nodes])
        full_off = np.concatenate([[0], np.cumsum(sizes_full)])
        node_full = np.concatenate(nodes)
        if not np.array_equal(node_full[~local.scene.dirichlet[node_full]], self.node_of_W):
            raise RuntimeError("rank-local assembly does not match the global W layout")
        keep = ~local.scene.dirichlet[node_full]
        self.K_W = self._block_diagonal(full_off, keep)
        self.f_W = np.concatenate(local.loads)[keep]
        self._free_local = [self.local_index[self.offsets[s]:self.offsets[s + 1]] for s in range(self.n_sub)]
        return self
