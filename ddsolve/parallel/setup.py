"""One rank's share of a problem: topology, owned subdomains, local assembly.

:func:`prepare_rank` is the parallel counterpart of :func:`ddsolve.prepared.prepare`.
Two ways, by method (:data:`SCATTERED`):

* **Scattered** (FETI-DP, BDDC, FETI and FETI-FETI): rank 0 alone builds the scene (reads or
  meshes and partitions the input) and the global topology, cuts them into one
  piece per rank (its part of the mesh with nodes renumbered, a
  :class:`~ddsolve.parallel.distribute.TopologySlice`, and the method's sharing
  lists) and scatters them. The other ranks never hold an array of the global
  size; rank 0 drops the global topology before the solve (it keeps the scene
  only for ``--check`` and ``--output``).
* **Replicated** (the hybrid and the active set method): every rank builds the scene and the
  global topology (integer metadata, no communication), as its methods read
  them across ranks.

Either way each rank assembles with NGSolve only its own part of the mesh
and builds its :class:`~ddsolve.parallel.distribute.RankSubstructures`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..dd.substructure import Substructures
from ..errors import InputError
from ..spec import ProblemSpec
from .comm import CountingComm
from .distribute import (
    RankSubstructures,
    TopologySlice,
    elements_by_rank,
    owned_range,
    owned_scene,
    rank_of_subdomain,
    topology,
)

__all__ = ["RankProblem", "SCATTERED", "prepare_rank", "gather_solution"]

#: Methods (problem poisson) whose rank pieces rank 0 computes and scatters; the others replicate the topology.
SCATTERED = ("fetidp", "bddc", "feti", "feti-feti")
PIECE_TAG = 11


@dataclass
class RankProblem:
    """What one rank holds for a distributed solve.

    Attributes
    ----------
    spec : ProblemSpec
    comm : CountingComm
    topo : Substructures or None
        Global topology (no float matrices, see :func:`~ddsolve.parallel.distribute.topology`):
        on every rank for a replicated method; for a scattered one (:data:`SCATTERED`) None, except
        on rank 0 when ``--check`` or ``--output`` needs it.
    sub : RankSubstructures
        The owned subdomains.
    rank_of_sub : ndarray of int, shape (n_sub,)
    timings : dict
        Seconds in ``"scene"``, ``"topology"``, ``"distribute"`` (cutting and scattering the pieces; 0
        for a replicated method), ``"assembly"``, ``"substructures"`` on this rank, and of the scene
        build ``"mesh"`` and ``"partition"`` (METIS; 0 on a structured scene or a given scene), as
        :attr:`ddsolve.prepared.Prepared.scene_timings`.
    gi : GlobalInterface or None
        The inter-body multipliers (problem multibody; contact: the contact pairs), built from the
        global topology.
    ndof, n_sub, n_primal : int
        Global counts.
    primal_dofs : ndarray of int
        Sorted global dofs of all primal unknowns (the coarse space, on every rank).
    pieces : dict
        A scattered method's sharing lists from rank 0 (``distribute_fetidp``, ``distribute_bddc``,
        ``distribute_feti``, ``distribute_fetifeti``).
    scene : Scene or None
        The global scene where it is kept (see ``topo``).
    """

    spec: ProblemSpec
    comm: CountingComm
    topo: Substructures | None
    sub: RankSubstructures
    rank_of_sub: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    gi: object = None
    ndof: int = 0
    n_sub: int = 0
    n_primal: int = 0
    primal_dofs: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    pieces: dict = field(default_factory=dict)
    scene: object = None


def _scene(spec: ProblemSpec, size: int, scene=None):
    """The global scene of ``spec`` (or ``scene``) and the ``mesh``/``partition`` seconds."""
    from ..prepared import scene_from_spec

    t0 = time.perf_counter()
    scene_timings = {"mesh": 0.0, "partition": 0.0}
    if scene is None:
        scene = scene_from_spec(spec)
        if spec.mesh == "unstructured":          # as ddsolve.prepared.prepare: METIS reported apart
            from ..scene.unstructured import LAST_TIMINGS
            scene_timings = {"mesh": LAST_TIMINGS.get("mesh", 0.0),
                             "partition": LAST_TIMINGS.get("split", 0.0) + LAST_TIMINGS.get("partition", 0.0)}
    if spec.mesh != "unstructured" or scene.element_type != "P1":
        scene_timings["mesh"] = time.perf_counter() - t0
    if scene.n_subdomains < size:          # a mesh file's parts are known only now
        raise InputError("parts", f"{scene.n_subdomains} subdomains for {size} ranks: need at least one "
                                  f"subdomain per rank")
    return scene, scene_timings


def prepare_rank(spec: ProblemSpec, comm: CountingComm, scene=None) -> RankProblem:
    """Build this rank's part of the problem of ``spec`` (or of ``scene``; every rank passes the same).

    Collective for a scattered method (rank 0 sends every rank its piece): an :class:`InputError` of
    rank 0 is raised on every rank.
    """
    if spec.method in SCATTERED:
        return _prepare_scattered(spec, comm, scene)
    from ..scene import assemble

    t0 = time.perf_counter()
    scene, scene_timings = _scene(spec, comm.size, scene)
    t1 = time.perf_counter()
    topo = topology(scene, spec.scaling, spec.gamma)
    gi = None
    if spec.problem in ("multibody", "contact"):
        from ..multibody import GlobalInterface
        gi = GlobalInterface(topo)
    t2 = time.perf_counter()
    lo, hi = owned_range(scene.n_subdomains, comm.size, comm.rank)
    local_scene, node_gid = owned_scene(scene, lo, hi)
    local = assemble(local_scene)
    t3 = time.perf_counter()
    sub = RankSubstructures.build(topo, local, node_gid, lo, hi, templates=spec.mesh != "unstructured")
    t4 = time.perf_counter()
    return RankProblem(spec=spec, comm=comm, topo=topo, sub=sub,
                       rank_of_sub=rank_of_subdomain(scene.n_subdomains, comm.size),
                       timings=dict(scene=t1 - t0, topology=t2 - t1, distribute=0.0, assembly=t3 - t2,
                                    substructures=t4 - t3, **scene_timings), gi=gi,
                       ndof=int(topo.ndof), n_sub=int(topo.n_sub), n_primal=int(topo.n_primal),
                       primal_dofs=np.unique(topo.l2g[topo.vertex]), scene=scene)


def _rank_pieces(spec: ProblemSpec, topo: Substructures, scene, size: int, with_scene: bool):
    """Rank 0: every rank's piece of a scattered method (its scene part, topology slice, sharing lists).

    A generator of ``(rank, piece)``, ranks in order, so that rank 0 holds one piece at a time
    besides its own.
    """
    from .bddc import distribute_bddc
    from .feti import distribute_feti
    from .fetidp import distribute_fetidp
    from .fetifeti import distribute_fetifeti

    n_sub = topo.n_sub
    rank_of_sub = rank_of_subdomain(n_sub, size)
    method = {"fetidp": distribute_fetidp, "bddc": distribute_bddc, "feti": distribute_feti,
              "feti-feti": distribute_fetifeti}[spec.method](topo, rank_of_sub, size, spec)
    primal_dofs = np.unique(topo.l2g[topo.vertex])
    n_primal = int(topo.n_primal)
    elements = elements_by_rank(scene, size) if with_scene else None
    for r in range(size):
        lo, hi = owned_range(n_sub, size, r)
        piece = {"slice": TopologySlice.of(topo, lo, hi, n_primal), "method": method[r],
                 "primal_dofs": primal_dofs, "n_sub": n_sub}
        if with_scene:
            piece["scene"] = owned_scene(scene, lo, hi, elements[r])
        yield r, piece


def _prepare_scattered(spec: ProblemSpec, comm: CountingComm, scene=None) -> RankProblem:
    """:func:`prepare_rank` of a scattered method: rank 0 builds, cuts and sends (one message per rank)."""
    from ..scene import assemble

    given = scene is not None
    t0 = time.perf_counter()
    pieces, error, timings = None, None, {"scene": 0.0, "topology": 0.0, "mesh": 0.0, "partition": 0.0}
    keep = comm.rank == 0 and (spec.check or bool(spec.output))
    topo = None
    if comm.rank == 0:
        try:
            scene, scene_timings = _scene(spec, comm.size, scene)
            t1 = time.perf_counter()
            topo = topology(scene, spec.scaling, spec.gamma)
            t2 = time.perf_counter()
            timings.update(scene=t1 - t0, topology=t2 - t1, **scene_timings)
            pieces = _rank_pieces(spec, topo, scene, comm.size, with_scene=not given)
        except InputError as exc:
            error = (exc.field, exc.message)
    t3 = t0 + timings["scene"] + timings["topology"]       # from here: cutting and sending (waiting elsewhere)
    error = comm.comm.bcast(error, root=0)
    if error is not None:
        raise InputError(*error)
    if comm.rank == 0:
        for r, cut in pieces:
            if r == 0:
                piece = cut
            else:
                comm.comm.send(cut, dest=r, tag=PIECE_TAG)
        del pieces, cut
    else:
        piece = comm.comm.recv(source=0, tag=PIECE_TAG)
    sl: TopologySlice = piece["slice"]
    local_scene, node_gid = owned_scene(scene, sl.lo, sl.hi) if given else piece["scene"]
    if not keep:
        topo = None
        scene = scene if given else None
    t4 = time.perf_counter()
    local = assemble(local_scene)
    t5 = time.perf_counter()
    sub = RankSubstructures.build(sl, local, node_gid, sl.lo, sl.hi, templates=spec.mesh != "unstructured")
    t6 = time.perf_counter()
    timings.update(distribute=t4 - t3, assembly=t5 - t4, substructures=t6 - t5)
    return RankProblem(spec=spec, comm=comm, topo=topo, sub=sub, rank_of_sub=rank_of_subdomain(piece["n_sub"], comm.size),
                       timings=timings, ndof=sl.ndof, n_sub=sl.n_sub, n_primal=sl.n_primal,
                       primal_dofs=piece["primal_dofs"], pieces=piece["method"], scene=scene if keep else None)


def gather_solution(prob: RankProblem, u_W: np.ndarray, root: int = 0) -> np.ndarray | None:
    """R_D^T u_W (delta-weighted average of the copies) assembled on ``root`` only, shape (ndof,)."""
    sub = prob.sub
    parts = prob.comm.gather((sub.l2g, sub.delta * u_W), root=root)
    if prob.comm.rank != root:
        return None
    l2g = np.concatenate([p[0] for p in parts])
    vals = np.concatenate([p[1] for p in parts])
    return np.bincount(l2g, weights=vals, minlength=prob.ndof)
