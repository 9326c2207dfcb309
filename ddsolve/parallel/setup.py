"""One rank's share of a problem: its part of the mesh, of the topology and of the method's lists.

:func:`prepare_rank` is the parallel counterpart of :func:`ddsolve.prepared.prepare`.
Rank 0 alone builds the scene (reads or meshes and partitions the input) and
the global topology, cuts them into one piece per rank (its part of the mesh
with nodes renumbered, a :class:`~ddsolve.parallel.distribute.TopologySlice`,
the method's sharing lists and the coarse dofs) and sends each rank its own.
The other ranks never hold an array of the global size; rank 0 drops the
global topology before the solve (it keeps the scene and the topology only
for ``--check`` and ``--output``). Each rank assembles with NGSolve only its
own part of the mesh and builds its
:class:`~ddsolve.parallel.distribute.RankSubstructures`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..dd.substructure import Substructures
from ..errors import InputError
from ..prepared import check_finite_matrices
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

__all__ = ["RankProblem", "prepare_rank", "gather_solution"]

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
        None, except on rank 0 when ``--check`` or ``--output`` needs it.
    sub : RankSubstructures
        The owned subdomains.
    rank_of_sub : ndarray of int, shape (n_sub,)
    timings : dict
        Seconds in ``"scene"``, ``"topology"``, ``"distribute"`` (cutting and sending the pieces on
        rank 0, waiting for its piece elsewhere), ``"assembly"``, ``"substructures"`` on this rank,
        and of the scene build ``"mesh"`` and ``"partition"`` (METIS; 0 on a structured scene or a
        given scene), as :attr:`ddsolve.prepared.Prepared.scene_timings`.
    ndof, n_sub, n_primal : int
        Global counts.
    primal_dofs : ndarray of int
        Sorted global dofs of all primal unknowns (the coarse space, on every rank).
    pieces : dict
        The method's lists from rank 0 (``distribute_fetidp``, ``distribute_bddc``,
        ``distribute_feti``, ``distribute_fetifeti``, ``distribute_hybrid``).
    scene : Scene or None
        The global scene where it is kept (see ``topo``).
    """

    spec: ProblemSpec
    comm: CountingComm
    topo: Substructures | None
    sub: RankSubstructures
    rank_of_sub: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    ndof: int = 0
    n_sub: int = 0
    n_primal: int = 0
    primal_dofs: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    pieces: dict = field(default_factory=dict)
    scene: object = None


def _scene(spec: ProblemSpec, size: int, scene=None):
    """The global scene of ``spec`` (or ``scene``) and the ``mesh``/``partition`` seconds."""
    from ..prepared import check_scene_decomposition, scene_from_spec, tied_scene

    t0 = time.perf_counter()
    scene_timings = {"mesh": 0.0, "partition": 0.0}
    if scene is None:
        scene = scene_from_spec(spec)
        if spec.mesh == "unstructured":          # as ddsolve.prepared.prepare: METIS reported apart
            from ..scene.unstructured import LAST_TIMINGS
            scene_timings = {"mesh": LAST_TIMINGS.get("mesh", 0.0),
                             "partition": LAST_TIMINGS.get("split", 0.0) + LAST_TIMINGS.get("partition", 0.0)}
    else:          # a user's scene, checked whole before it is cut (its cut parts no longer show an id of -1)
        scene.check()
    scene = tied_scene(spec, scene)            # as ddsolve.prepare: multibody ties carry the Dirichlet condition
    check_scene_decomposition(spec, scene)
    if spec.mesh != "unstructured" or scene.element_type != "P1":
        scene_timings["mesh"] = time.perf_counter() - t0
    if scene.n_subdomains < size:          # a mesh file's parts are known only now
        raise InputError("parts", f"{scene.n_subdomains} subdomains for {size} ranks: need at least one "
                                  f"subdomain per rank")
    return scene, scene_timings


def _rank_pieces(spec: ProblemSpec, topo: Substructures, scene, size: int, with_scene: bool):
    """Rank 0: every rank's piece (its scene part, topology slice, the method's lists).

    The method's lists are computed here (so that their errors are raised here); the pieces come
    from the returned generator of ``(rank, piece)``, ranks in order, cut one at a time so that
    rank 0 holds one piece besides its own.
    """
    from .bddc import distribute_bddc
    from .feti import distribute_feti
    from .fetidp import distribute_fetidp
    from .fetifeti import distribute_fetifeti
    from .hybrid import distribute_hybrid

    n_sub = topo.n_sub
    rank_of_sub = rank_of_subdomain(n_sub, size)
    method = {"fetidp": distribute_fetidp, "bddc": distribute_bddc, "feti": distribute_feti,
              "feti-feti": distribute_fetifeti, "hybrid": distribute_hybrid,
              "active-set": distribute_hybrid}[spec.method](topo, rank_of_sub, size, spec)
    primal_dofs = np.unique(topo.l2g[topo.vertex])
    n_primal = int(primal_dofs.size)               # topo.n_primal: primal "vertices" only under mpiexec
    elements = elements_by_rank(scene, size) if with_scene else None

    def cut(r: int) -> dict:
        lo, hi = owned_range(n_sub, size, r)
        piece = {"slice": TopologySlice.of(topo, lo, hi, n_primal), "method": method[r],
                 "primal_dofs": primal_dofs, "n_sub": n_sub}
        if with_scene:
            piece["scene"] = owned_scene(scene, lo, hi, elements[r])
        return piece

    return ((r, cut(r)) for r in range(size))


def prepare_rank(spec: ProblemSpec, comm: CountingComm, scene=None) -> RankProblem:
    """Build this rank's part of the problem of ``spec`` (or of rank 0's ``scene``).

    Collective: rank 0 builds the scene and the topology, cuts them and sends every rank its piece
    (one message per rank). An :class:`InputError` of rank 0 is raised on every rank. Only rank 0
    reads the spec's mesh file. A ``scene`` is needed on rank 0 only; where every rank passes the
    same scene, each cuts its own part from it (so a callable load ``scene.f``, which cannot be
    sent, needs the scene on every rank).
    """
    from ..scene import assemble

    t0 = time.perf_counter()
    given = all(comm.comm.allgather(scene is not None))      # every rank cuts its own part of the scene
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
            if not given and callable(scene.f) and comm.size > 1:
                raise InputError("scene", "a callable load f cannot be sent to the other ranks: pass the same "
                                          "scene on every rank (or element-wise loads, an ndarray)")
            pieces = _rank_pieces(spec, topo, scene, comm.size, with_scene=not given)
        except InputError as exc:
            error = (exc.field, exc.message)
    t3 = t0 + timings["scene"] + timings["topology"]       # from here: cutting and sending (waiting elsewhere)
    error = comm.comm.bcast(error, root=0)
    if error is not None:
        raise InputError(*error)
    if given and comm.rank != 0:   # passed on rank 0 (the same scene): the same arrays and ties here too
        from ..prepared import tied_scene

        scene.check()
        scene = tied_scene(spec, scene)
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
        topo = None                                         # the scene is dropped at the return
    t4 = time.perf_counter()
    local = assemble(local_scene)
    t5 = time.perf_counter()
    sub = RankSubstructures.build(sl, local, node_gid, templates=spec.mesh != "unstructured")
    check_finite_matrices(sub, spec.mesh_file)
    t6 = time.perf_counter()
    timings.update(distribute=t4 - t3, assembly=t5 - t4, substructures=t6 - t5)
    return RankProblem(spec=spec, comm=comm, topo=topo, sub=sub,
                       rank_of_sub=rank_of_subdomain(piece["n_sub"], comm.size),
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
