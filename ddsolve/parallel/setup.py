"""One rank's share of a problem: topology, owned subdomains, local assembly.

:func:`prepare_rank` is the parallel counterpart of :func:`ddsolve.prepared.prepare`
(Poisson only): scene (every rank, same numbers), topology (every rank,
integer metadata), NGSolve assembly of the owned subdomains only, and the
:class:`~ddsolve.parallel.distribute.RankSubstructures`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..dd.substructure import Substructures
from ..spec import ProblemSpec
from .comm import CountingComm
from .distribute import RankSubstructures, owned_range, owned_scene, rank_of_subdomain, topology

__all__ = ["RankProblem", "prepare_rank", "gather_solution"]


@dataclass
class RankProblem:
    """What one rank holds for a distributed solve.

    Attributes
    ----------
    spec : ProblemSpec
    comm : CountingComm
    topo : Substructures
        Global topology (no float matrices, see :func:`~ddsolve.parallel.distribute.topology`).
    sub : RankSubstructures
        The owned subdomains.
    rank_of_sub : ndarray of int, shape (n_sub,)
    timings : dict
        Seconds in ``"scene"``, ``"topology"``, ``"assembly"``, ``"substructures"`` on this rank, and
        of the scene build ``"mesh"`` and ``"partition"`` (METIS; 0 on a structured scene or a given
        scene), as :attr:`ddsolve.prepared.Prepared.scene_timings`.
    gi : GlobalInterface or None
        The inter-body multipliers (problem multibody; contact: the contact pairs), built from the
        global topology.
    """

    spec: ProblemSpec
    comm: CountingComm
    topo: Substructures
    sub: RankSubstructures
    rank_of_sub: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    gi: object = None


def prepare_rank(spec: ProblemSpec, comm: CountingComm, scene=None) -> RankProblem:
    """Build this rank's part of the problem of ``spec`` (or of ``scene``)."""
    from ..prepared import scene_from_spec
    from ..scene import assemble

    t0 = time.perf_counter()
    scene_timings = {"mesh": 0.0, "partition": 0.0}
    if scene is None:
        scene = scene_from_spec(spec)
        if spec.mesh == "unstructured":          # as ddsolve.prepared.prepare: METIS reported apart
            from ..scene.unstructured import LAST_TIMINGS
            scene_timings = {"mesh": LAST_TIMINGS.get("mesh", 0.0),
                             "partition": LAST_TIMINGS.get("split", 0.0) + LAST_TIMINGS.get("partition", 0.0)}
    t1 = time.perf_counter()
    if spec.mesh != "unstructured" or scene.element_type != "P1":
        scene_timings["mesh"] = t1 - t0
    if scene.n_subdomains < comm.size:          # a mesh file's parts are known only now (no communication yet)
        from ..errors import InputError
        raise InputError("parts", f"{scene.n_subdomains} subdomains for {comm.size} ranks: need at least one "
                                  f"subdomain per rank")
    topo = topology(scene, spec.scaling, spec.gamma)
    gi = None
    if spec.problem in ("multibody", "contact"):
        from ..multibody import GlobalInterface
        gi = GlobalInterface(topo)
    t2 = time.perf_counter()
    lo, hi = owned_range(scene.n_subdomains, comm.size, comm.rank)
    local = assemble(owned_scene(scene, lo, hi))
    t3 = time.perf_counter()
    sub = RankSubstructures.build(topo, local, lo, hi, templates=spec.mesh != "unstructured")
    t4 = time.perf_counter()
    return RankProblem(spec=spec, comm=comm, topo=topo, sub=sub,
                       rank_of_sub=rank_of_subdomain(scene.n_subdomains, comm.size),
                       timings=dict(scene=t1 - t0, topology=t2 - t1, assembly=t3 - t2, substructures=t4 - t3,
                                    **scene_timings), gi=gi)


def gather_solution(prob: RankProblem, u_W: np.ndarray, root: int = 0) -> np.ndarray | None:
    """R_D^T u_W (delta-weighted average of the copies) assembled on ``root`` only, shape (ndof,)."""
    sub = prob.sub
    parts = prob.comm.gather((sub.l2g, sub.delta * u_W), root=root)
    if prob.comm.rank != root:
        return None
    l2g = np.concatenate([p[0] for p in parts])
    vals = np.concatenate([p[1] for p in parts])
    return np.bincount(l2g, weights=vals, minlength=prob.topo.ndof)
