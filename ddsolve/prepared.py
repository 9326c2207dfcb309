"""One path from a :class:`~ddsolve.spec.ProblemSpec` to an assembled, decomposed problem.

``prepare(spec)`` is the chain spec -> scene -> NGSolve assembly ->
:class:`~ddsolve.dd.Substructures` (-> :class:`~ddsolve.contact.ContactProblem`
for contact) that :func:`ddsolve.solve`, the studies and the tests share.
Assembly (here) is kept apart from the solve (:mod:`ddsolve.api`), as in
scikit-fem.
"""
from __future__ import annotations

import dataclasses
import logging
import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import InputError
from .spec import ProblemSpec, parse_f, parse_rho

if TYPE_CHECKING:  # pragma: no cover
    from .contact.problem import ContactProblem
    from .dd.substructure import Substructures
    from .scene import LocalProblems, Scene

__all__ = ["Prepared", "prepare", "scene_from_spec", "unstructured_scene_from_spec", "check_decomposition"]

log = logging.getLogger(__name__)

#: InputError fields of :func:`ddsolve.scene.unstructured.scene_from_mesh` -> the spec fields they stand for.
_MESH_FILE_FIELDS = {"mesh": "mesh_file", "bodies": "bodies_materials", "contact": "contact_boundary"}


def scene_from_spec(spec: ProblemSpec) -> "Scene":
    """The structured scene of a spec, with its coefficient pattern and load applied.

    Raises
    ------
    InputError
        For a contact load whose integral over the floating membrane is not negative.
    """
    from .scene import checkerboard, structured_square
    from .scene.contact import two_membranes

    if spec.mesh == "unstructured":
        return unstructured_scene_from_spec(spec)
    kind, value = parse_rho(spec.rho)
    f_kind, f_value = parse_f(spec.f)
    if spec.problem == "contact":
        n_el = 2 * (spec.subdomains * spec.elements) ** 2
        if f_kind == "dostal":
            scene = two_membranes(spec.subdomains, spec.elements, patches=f_value)
        elif f_kind == "random":
            scene = two_membranes(spec.subdomains, spec.elements,
                                  f=np.random.default_rng(int(f_value)).uniform(-1.0, 1.0, n_el))
        else:
            scene = two_membranes(spec.subdomains, spec.elements, f=f_value)
    else:
        scene = structured_square(spec.bodies, spec.subdomains, spec.elements, rho=1.0)
        if f_kind == "random":
            scene.f = np.random.default_rng(int(f_value)).uniform(-1.0, 1.0, scene.elements.shape[0])
        else:
            scene.f = f_value
    if kind == "checkerboard":
        scene.rho = checkerboard(scene.subdomain_grid, value)
    elif kind == "body-checkerboard":
        # (column, row) of each subdomain's body: every body has subdomains x subdomains subdomains
        scene.rho = checkerboard(scene.subdomain_grid // spec.subdomains, value)
    else:
        scene.rho = np.full(scene.n_subdomains, value)
    return scene


def unstructured_scene_from_spec(spec: ProblemSpec) -> "Scene":
    """The P1 scene of a spec with ``mesh == "unstructured"`` (a built-in geometry or ``mesh_file``).

    Coefficient patterns (there is no subdomain grid): ``checkerboard:V`` puts
    rho = V on the odd-numbered METIS parts of every body (subdomain
    ``body * parts + part``), 1 elsewhere; ``body-checkerboard:V`` alternates
    over the bodies like a chess board (multibody: body ``by * bodies + bx``;
    contact and mesh files: by body index parity). ``f: random:SEED`` draws one
    value per triangle.

    Raises
    ------
    InputError
        Naming the spec field: ``parts`` (more parts than elements),
        ``mesh_file`` (missing or not a netgen mesh), ``bodies_materials``,
        ``dirichlet``, ``contact_boundary`` (unknown names, a non-conforming
        interface with its location), ``f`` (a contact load that does not press
        Omega^2 onto Omega^1).
    """
    from .scene.contact import check_contact_load, floating_bodies
    from .scene.unstructured import scene_from_mesh, unstructured_scene

    kind, value = parse_rho(spec.rho)
    f_kind, f_value = parse_f(spec.f)
    contact = spec.problem == "contact"
    if spec.mesh_file:
        names = [n for n in spec.bodies_materials.split(",") if n] or None
        dirichlet: Any = "boundary" if spec.dirichlet == "boundary" else spec.dirichlet.split(",")
        try:
            scene = scene_from_mesh(spec.mesh_file, bodies=names, dirichlet=dirichlet,
                                    contact=spec.contact_boundary if contact else None, parts=spec.parts,
                                    refine=spec.refine, f=1.0, one_body=spec.problem == "poisson")
        except InputError as exc:
            raise InputError(_MESH_FILE_FIELDS.get(exc.field, exc.field), exc.message) from None
        if contact and scene.n_bodies != 2:
            raise InputError("bodies_materials", f"problem 'contact' needs two bodies, the mesh file has "
                                                 f"{scene.n_bodies}")
        if contact and f_kind == "dostal":
            from .scene.contact import dostal_loads
            scene.f = dostal_loads(scene.coords[scene.elements].mean(axis=1), *f_value)
    else:
        scene = unstructured_scene(spec.problem, geometry=spec.geometry, maxh=spec.maxh, refine=spec.refine,
                                   parts=spec.parts, bodies=spec.bodies if spec.problem == "multibody" else 1,
                                   f=(None if f_kind == "dostal" else f_value if f_kind == "constant" else -1.0),
                                   patches=f_value if f_kind == "dostal" else (-3.0, -1.0))
    if f_kind == "random":
        scene.f = np.random.default_rng(int(f_value)).uniform(-1.0, 1.0, scene.elements.shape[0])
    elif f_kind == "constant" and spec.mesh_file:
        scene.f = float(f_value)
    if contact and (spec.mesh_file or f_kind == "random"):
        check_contact_load(scene, scene.f)
    if contact and spec.method == "smalbe":
        check_smalbe_scene(floating_bodies(scene))
    part = np.arange(scene.n_subdomains) % spec.parts
    if kind == "checkerboard":
        scene.rho = np.where(part % 2 == 1, value, 1.0)
    elif kind == "body-checkerboard":
        body = scene.subdomain_body
        if spec.problem == "multibody" and not spec.mesh_file:
            parity = (body % spec.bodies + body // spec.bodies) % 2
        else:
            parity = body % 2
        scene.rho = np.where(parity == 1, value, 1.0)
    else:
        scene.rho = np.full(scene.n_subdomains, value)
    return scene


def check_smalbe_scene(floating: list[bool]) -> None:
    """SMALBE (Chapter 6) solves the setting of (3.1) only: body 1 clamped, body 2 floating.

    Raises
    ------
    InputError
        ``method``, for any other pair of clamped and floating bodies.
    """
    if list(floating) != [False, True]:
        state = " and ".join(f"body {k + 1} {'floats' if f else 'is clamped'}" for k, f in enumerate(floating))
        raise InputError("method", f"'smalbe' (Chapter 6) needs body 1 clamped and body 2 floating, as in (3.1); "
                                   f"here {state}: use 'active-set' or 'direct'")


def check_decomposition(spec: ProblemSpec) -> None:
    """Reject decompositions that a substructuring method cannot handle.

    Raises
    ------
    InputError
        ``subdomains``: a DD method on one subdomain per body side where that
        leaves nothing to iterate on (poisson: no interface) or a floating body
        without a primal vertex (multibody with 1/H_b >= 3, whose inner bodies
        float; contact, whose Omega^2 floats): the generalized inverse of a
        floating body pins one of its primal vertices.
    """
    if spec.method == "direct":
        return
    # the structured rules read subdomains (per body side), the unstructured ones parts (per body)
    if spec.mesh == "unstructured":
        field, count, what = "parts", spec.parts, "parts per body"
        if spec.mesh_file:
            return
    else:
        field, count, what = "subdomains", spec.subdomains, "subdomains per body side"
    if count != 1:
        return
    if spec.problem == "poisson" or (spec.problem == "multibody" and spec.bodies == 1):   # one subdomain in all
        raise InputError(field, f"method {spec.method!r} needs at least 2 {what.split(' per')[0]} "
                                f"(one subdomain has no interface); use method 'direct'")
    if spec.problem == "contact" or (spec.problem == "multibody" and spec.bodies >= 3):
        raise InputError(field, f"method {spec.method!r} needs at least 2 {what} when a body floats "
                                f"(a floating body pins one of its primal vertices, and a one-subdomain "
                                f"body has none); use method 'direct'")


#: Below this largest rho, non-finite subdomain matrices come from the mesh, not from rho.
RHO_OVERFLOW_SUSPECT = 1e100


def check_finite_matrices(sub: Substructures, mesh_file: str | None = None) -> None:
    """Refuse subdomain matrices whose entries overflow: rho times an element matrix entry above the
    largest double (``--rho 1e308`` on Q1: a breakdown at iteration 0 and an overflow warning before), or a
    mesh whose coordinates are so small that its element Jacobians underflow (a mesh file scaled by
    1e-153; a review found the error blaming rho = 1 then: it names ``mesh_file`` now)."""
    if np.all(np.isfinite(sub.K_W.data)):
        return
    largest = float(np.max(sub.rho))
    if largest < RHO_OVERFLOW_SUSPECT:
        raise InputError("mesh_file" if mesh_file else "mesh",
                         f"the element matrices are not finite (rho is at most {largest:.3g}): element sizes near "
                         f"the limits of double precision (coordinates of 1e-150?); rescale the mesh")
    raise InputError("rho", f"the largest rho, {largest:.3g}, times the element matrices overflows "
                            f"the largest double ({sys.float_info.max:.3g}): rescale the problem")


def tied_scene(spec: ProblemSpec, scene: "Scene") -> "Scene":
    """``scene`` with the Dirichlet condition carried to every body's copy of a clamped point where the
    bodies are tied at every shared point (problem multibody with ``contact="full"``, case I:
    :meth:`~ddsolve.scene.scene.Scene.tied_dirichlet`); else ``scene``.

    Case II (``contact="middle"``) ties the middles of the faces only: a copy at a face's end is not tied,
    and its own condition stays (a review: the first version clamped it there too, another problem). A
    caller that prepares with ``"full"`` and then solves with another active mask
    (``HybridSolver.solve(gi.contact_mask("middle"))``) keeps the full case's mask.

    A new scene where the mask changes (the caller's is not modified); logged at INFO.
    """
    if spec.problem != "multibody" or spec.contact != "full":
        return scene
    tied = scene.tied_dirichlet()
    added = int(np.count_nonzero(tied & ~np.asarray(scene.dirichlet, dtype=bool)))
    if not added:
        return scene
    log.info("multibody: %d node copies made Dirichlet, tied to a clamped copy of the same point", added)
    return dataclasses.replace(scene, dirichlet=tied)


def check_scene_decomposition(spec: ProblemSpec, scene: "Scene") -> None:
    """What :func:`check_decomposition` cannot see before a mesh file is read, checked on its scene.

    Raises
    ------
    InputError
        ``parts``: one subdomain in all (poisson), or a floating body of one subdomain (a floating
        body pins one of its primal vertices); ``dirichlet``: a body of a multibody scene that no
        chain of tied interfaces joins to a clamped body (the problem is singular).
    """
    if spec.method == "direct" or not spec.mesh_file:
        return
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from .scene.contact import floating_bodies

    if spec.problem == "poisson" and scene.n_subdomains == 1:
        raise InputError("parts", f"method {spec.method!r} needs at least 2 parts (one subdomain has no "
                                  f"interface); use method 'direct'")
    floating = np.array(floating_bodies(scene), dtype=bool)
    parts = np.bincount(scene.subdomain_body, minlength=scene.n_bodies)
    lonely = np.flatnonzero(floating & (parts == 1))
    if lonely.size:
        raise InputError("parts", f"method {spec.method!r} needs 2 or more parts per floating body, body "
                                  f"{int(lonely[0]) + 1} has 1: raise parts or use method 'direct'")
    if spec.problem == "multibody" and scene.n_bodies > 1 and floating.any():
        node_body = np.zeros(scene.n_nodes, dtype=np.int64)
        node_body[scene.elements] = scene.subdomain_body[scene.element_subdomain][:, None]
        # bodies tied wherever they share a point, as the solvers tie them (multibody.interface), also at a
        # corner alone: the pairs of the shared edges (contact_pairs) left such a body "joined to no clamped
        # body" although the solvers tie it (a review)
        loc = scene.locations()
        order = np.argsort(loc, kind="stable")
        same = loc[order[1:]] == loc[order[:-1]]
        a, b = node_body[order[:-1][same]], node_body[order[1:][same]]
        graph = coo_matrix((np.ones(a.size), (a, b)), shape=(scene.n_bodies, scene.n_bodies))
        _, label = connected_components(graph, directed=False)
        held = np.zeros(label.max() + 1, dtype=bool)
        held[label[~floating]] = True
        loose = np.flatnonzero(~held[label])
        if loose.size:
            raise InputError("dirichlet", f"body {int(loose[0]) + 1} is joined to no clamped body by tied "
                                          f"interfaces (it floats freely: the problem is singular); clamp it "
                                          f"or tie it to a clamped body")


@dataclass(frozen=True)
class Prepared:
    """An assembled and decomposed problem, ready for any method of its problem kind.

    Attributes
    ----------
    spec : ProblemSpec
        The specification it was built from.
    scene : Scene
        Geometry, decomposition, coefficient and load.
    local : LocalProblems
        NGSolve-assembled subdomain matrices and loads.
    sub : Substructures
        The unassembled space W and the subdomain operators (with the spec's scaling).
    contact : ContactProblem or None
        The assembled contact problem (3.1) (``problem == "contact"`` only).
    timings : dict
        Seconds spent in ``"scene"``, ``"assembly"`` and ``"substructures"`` (and ``"contact"``).
    scene_timings : dict
        The part of ``"scene"`` spent in ``"mesh"`` (netgen meshing, refinement, reading a
        mesh file; the structured generator) and ``"partition"`` (splitting bodies, METIS);
        not added to :attr:`seconds` again.
    """

    spec: ProblemSpec
    scene: "Scene"
    local: "LocalProblems"
    sub: "Substructures"
    contact: "ContactProblem | None" = None
    timings: dict[str, float] = field(default_factory=dict)
    scene_timings: dict[str, float] = field(default_factory=dict)

    @property
    def seconds(self) -> float:
        """Total preparation time."""
        return float(sum(self.timings.values()))


def prepare(spec: ProblemSpec | dict[str, Any], scene: "Scene | None" = None) -> Prepared:
    """Build, assemble and decompose the problem of ``spec``.

    Parameters
    ----------
    spec : ProblemSpec or dict
        A dict is validated with :meth:`ProblemSpec.from_mapping`.
    scene : Scene, optional
        A scene to use instead of :func:`scene_from_spec` (e.g. a study's own
        load); ``spec`` still supplies the scaling and the problem kind.

    Returns
    -------
    Prepared

    Raises
    ------
    InputError
        Invalid specification or decomposition.
    """
    from .dd.substructure import Substructures
    from .scene import assemble

    if not isinstance(spec, ProblemSpec):
        spec = ProblemSpec.from_mapping(spec)
    check_decomposition(spec)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    scene_timings = {"mesh": 0.0, "partition": 0.0}
    if scene is None:
        scene = scene_from_spec(spec)
        if spec.mesh == "unstructured":
            from .scene.unstructured import LAST_TIMINGS
            scene_timings = {"mesh": LAST_TIMINGS.get("mesh", 0.0),
                             "partition": LAST_TIMINGS.get("split", 0.0) + LAST_TIMINGS.get("partition", 0.0)}
    scene = tied_scene(spec, scene)
    check_scene_decomposition(spec, scene)
    rho = np.asarray(scene.rho, dtype=float)
    wrong = ~(np.isfinite(rho) & (rho > 0.0))          # a user's scene (a spec's rho is validated)
    if wrong.any():
        bad = int(np.flatnonzero(wrong)[0])
        raise InputError("rho", f"the scene's coefficient of subdomain {bad} is {float(rho[bad])!r}: every subdomain "
                                f"needs a positive finite rho")
    t1 = time.perf_counter()
    if spec.mesh != "unstructured" or scene.element_type != "P1":
        scene_timings["mesh"] = t1 - t0
    local = assemble(scene)
    t2 = time.perf_counter()
    sub = Substructures(local, scaling=spec.scaling, gamma=spec.gamma, templates=spec.mesh != "unstructured",
                        primal=spec.primal)
    check_finite_matrices(sub, spec.mesh_file)
    t3 = time.perf_counter()
    timings.update(scene=t1 - t0, assembly=t2 - t1, substructures=t3 - t2)
    contact = None
    if spec.problem == "contact":
        from .contact.problem import ContactProblem
        contact = ContactProblem(sub)
        timings["contact"] = time.perf_counter() - t3
    return Prepared(spec=spec, scene=scene, local=local, sub=sub, contact=contact, timings=timings,
                    scene_timings=scene_timings)
