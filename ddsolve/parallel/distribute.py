"""Distribution of the subdomains over MPI ranks: the rank-local substructures.

Ownership. Subdomains are the unit: rank r owns the contiguous block
``owned_range(n_sub, P, r)`` of subdomain numbers (on a METIS scene the
subdomains of a body are its METIS parts, numbered part by part).

What a rank holds (:mod:`ddsolve.parallel.setup` builds it).

* The *topology* (:func:`topology`): node lists, interface classification
  (multiplicity, cross points, primal vertices completed by
  :meth:`Substructures._anchor_floating`), the delta-dagger weights and the
  global numbering of multipliers / interface dofs, derived from the global
  mesh. Rank 0 alone computes it and sends every rank its
  :class:`TopologySlice` (the owned W entries) and its part of the mesh
  (:func:`owned_scene`, nodes renumbered).
* Its own :class:`RankSubstructures`: a :class:`~ddsolve.dd.Substructures`
  restricted to the owned subdomains, assembled by NGSolve on the owned part of
  the mesh only, with the owned W entries (the W layout is subdomain by
  subdomain, so they are one contiguous slice of the global W). Every float
  array of the solve (matrices, factorizations, loads, iterates) is rank-local.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..dd.substructure import Substructures
from ..scene.scene import Scene, sorted_unique

__all__ = ["owned_range", "rank_of_subdomain", "topology", "owned_scene", "elements_by_rank", "TopologySlice",
           "RankSubstructures"]


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


def owned_scene(scene: Scene, lo: int, hi: int, el: np.ndarray | None = None) -> tuple[Scene, np.ndarray]:
    """The scene restricted to subdomains [lo, hi): subdomains renumbered from 0, nodes renumbered.

    The nodes of the owned elements are numbered 0..m-1 in increasing global order (so the
    canonical local order of every subdomain, :meth:`Scene.subdomain_layout`, is that of the
    global scene); no array of the result has the global size.

    Parameters
    ----------
    scene : Scene
    lo, hi : int
    el : ndarray of int, optional
        The elements of subdomains [lo, hi), ascending (:func:`elements_by_rank`; default: found by a
        pass over all elements).

    Returns
    -------
    scene : Scene
    node_gid : ndarray of int, shape (m,)
        Global node number of each local node (sorted).
    """
    if el is None:
        el = np.flatnonzero((scene.element_subdomain >= lo) & (scene.element_subdomain < hi))
    elements = scene.elements[el]
    node_gid = sorted_unique(elements.ravel())
    f = scene.f
    if isinstance(f, np.ndarray):
        f = np.asarray(f)[el]
    grid = None if scene.subdomain_grid is None else scene.subdomain_grid[lo:hi]
    local = replace(scene, coords=scene.coords[node_gid],
                    elements=np.searchsorted(node_gid, elements).astype(scene.elements.dtype),
                    element_subdomain=scene.element_subdomain[el] - lo, dirichlet=scene.dirichlet[node_gid],
                    subdomain_body=scene.subdomain_body[lo:hi], rho=np.asarray(scene.rho)[lo:hi], f=f,
                    subdomain_grid=grid, contact_pairs=np.zeros((0, 2), dtype=np.int64))
    return local, node_gid


def elements_by_rank(scene: Scene, size: int) -> list[np.ndarray]:
    """The elements of each rank's subdomains (:func:`owned_range`), ascending: one sort for all ranks."""
    order = np.argsort(scene.element_subdomain, kind="stable")
    first_sub = [owned_range(scene.n_subdomains, size, r)[0] for r in range(size)] + [scene.n_subdomains]
    bounds = np.searchsorted(scene.element_subdomain[order], first_sub)
    return [np.sort(order[bounds[r]:bounds[r + 1]]) for r in range(size)]


#: Per-W-entry arrays of a :class:`TopologySlice` (the slice w0:w1 of the global topology's).
W_FIELDS = ("node_of_W", "sub_of_W", "local_index", "l2g", "multiplicity", "interface", "cross_point",
            "vertex", "delta")


@dataclass
class TopologySlice:
    """The part of the global topology one rank's subdomains [lo, hi) need (no global-size array).

    Attributes
    ----------
    lo, hi : int
        Owned subdomains.
    w0, w1 : int
        Their slice of the global W.
    n_sub, n_W, ndof, n_primal : int
        Global counts.
    scaling : str
    gamma : float
    primal : str
    rho, body_of_sub, floating_sub : ndarray, shape (hi - lo,)
    offsets : ndarray of int, shape (hi - lo + 1,)
        Global W offsets of the owned subdomains.
    node_of_W, sub_of_W, local_index, l2g, multiplicity, interface, cross_point, vertex, delta : ndarray
        Shape (w1 - w0,) each: the global topology's arrays on the owned W entries (global node,
        subdomain and dof numbers).
    """

    lo: int
    hi: int
    w0: int
    w1: int
    n_sub: int
    n_W: int
    ndof: int
    n_primal: int
    scaling: str
    gamma: float
    primal: str
    rho: np.ndarray
    body_of_sub: np.ndarray
    floating_sub: np.ndarray
    offsets: np.ndarray
    node_of_W: np.ndarray
    sub_of_W: np.ndarray
    local_index: np.ndarray
    l2g: np.ndarray
    multiplicity: np.ndarray
    interface: np.ndarray
    cross_point: np.ndarray
    vertex: np.ndarray
    delta: np.ndarray

    @classmethod
    def of(cls, topo: Substructures, lo: int, hi: int, n_primal: int | None = None) -> "TopologySlice":
        """Copies of ``topo``'s arrays restricted to the subdomains [lo, hi) (``n_primal``: ``topo.n_primal``
        when known)."""
        w0, w1 = int(topo.offsets[lo]), int(topo.offsets[hi])
        return cls(lo=lo, hi=hi, w0=w0, w1=w1, n_sub=int(topo.n_sub), n_W=int(topo.n_W), ndof=int(topo.ndof),
                   n_primal=int(topo.n_primal if n_primal is None else n_primal), scaling=topo.scaling,
                   gamma=float(topo.gamma), primal=topo.primal,
                   rho=np.array(topo.rho[lo:hi]), body_of_sub=np.array(topo.body_of_sub[lo:hi]),
                   floating_sub=np.array(topo.floating_sub[lo:hi]), offsets=np.array(topo.offsets[lo:hi + 1]),
                   **{name: np.array(getattr(topo, name)[w0:w1]) for name in W_FIELDS})


class RankSubstructures(Substructures):
    """:class:`Substructures` of one rank's subdomains [lo, hi), classified globally.

    Built by :meth:`build` (not by the parent constructor): the layout arrays
    are those of the rank's :class:`TopologySlice` (the slice ``w0:w1`` of the
    global topology's), ``sub_of_W`` counts from 0 at ``lo``, ``l2g`` keeps the
    global dof numbers, and ``K_W``, ``f_W``, ``stiffness`` come from the local
    NGSolve assembly. The serial operators
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
    def build(cls, sl: TopologySlice, local, node_gid: np.ndarray, templates: bool = True) -> "RankSubstructures":
        """``sl``: the rank's :class:`TopologySlice` (subdomains [sl.lo, sl.hi)); ``local``: the
        :class:`~ddsolve.scene.LocalProblems` of :func:`owned_scene` of those subdomains and ``node_gid``
        its global node numbers; ``templates`` as for :class:`Substructures` (False: every subdomain
        distinct, batched factorizations)."""
        lo, hi = sl.lo, sl.hi
        self = cls.__new__(cls)
        self.lo, self.hi, self.w0, self.w1 = lo, hi, sl.w0, sl.w1
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
        self.rho = sl.rho
        self.body_of_sub = sl.body_of_sub
        for name in W_FIELDS:
            setattr(self, name, getattr(sl, name))
        self.sub_of_W = sl.sub_of_W - lo
        self.n_W = sl.w1 - sl.w0
        self.offsets = sl.offsets - sl.w0
        self.floating_sub = sl.floating_sub
        self.ndof = sl.ndof
        self.primal = sl.primal
        self.scaling, self.gamma = sl.scaling, sl.gamma
        nodes = local.nodes
        sizes_full = np.array([len(nd) for nd in nodes])
        full_off = np.concatenate([[0], np.cumsum(sizes_full)])
        node_full = np.concatenate(nodes)
        keep = ~local.scene.dirichlet[node_full]
        if not np.array_equal(node_gid[node_full[keep]], self.node_of_W):
            raise RuntimeError("rank-local assembly does not match the global W layout")
        self.K_W = self._block_diagonal(full_off, keep)
        self.f_W = np.concatenate(local.loads)[keep]
        self._free_local = [self.local_index[self.offsets[s]:self.offsets[s + 1]] for s in range(self.n_sub)]
        return self
