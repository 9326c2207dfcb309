"""One path from a :class:`~ddsolve.spec.ProblemSpec` to an assembled, decomposed problem.

``prepare(spec)`` is the chain spec -> scene -> NGSolve assembly ->
:class:`~ddsolve.dd.Substructures` (-> :class:`~ddsolve.contact.ContactProblem`
for contact) that :func:`ddsolve.solve`, the studies and the tests share.
Assembly (here) is kept apart from the solve (:mod:`ddsolve.api`), as in
scikit-fem.
"""
from __future__ import annotations

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

__all__ = ["Prepared", "prepare", "scene_from_spec", "check_decomposition"]


def scene_from_spec(spec: ProblemSpec) -> "Scene":
    """The structured scene of a spec, with its coefficient pattern and load applied.

    Raises
    ------
    InputError
        For a contact load whose integral over the floating membrane is not negative.
    """
    from .scene import checkerboard, structured_square
    from .scene.contact import two_membranes

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
    if spec.method == "direct" or spec.subdomains != 1:
        return
    if spec.problem == "poisson":
        raise InputError("subdomains", f"method {spec.method!r} needs at least 2 subdomains per side "
                                       f"(one subdomain has no interface); use method 'direct'")
    if spec.problem == "contact" or (spec.problem == "multibody" and spec.bodies >= 3):
        raise InputError("subdomains", f"method {spec.method!r} needs at least 2 subdomains per body side "
                                       f"when a body floats (a floating body pins one of its primal "
                                       f"vertices, and a one-subdomain body has none); use method 'direct'")


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
    """

    spec: ProblemSpec
    scene: "Scene"
    local: "LocalProblems"
    sub: "Substructures"
    contact: "ContactProblem | None" = None
    timings: dict[str, float] = field(default_factory=dict)

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
    if scene is None:
        scene = scene_from_spec(spec)
    t1 = time.perf_counter()
    local = assemble(scene)
    t2 = time.perf_counter()
    sub = Substructures(local, scaling=spec.scaling, gamma=spec.gamma)
    t3 = time.perf_counter()
    timings.update(scene=t1 - t0, assembly=t2 - t1, substructures=t3 - t2)
    contact = None
    if spec.problem == "contact":
        from .contact.problem import ContactProblem
        contact = ContactProblem(sub)
        timings["contact"] = time.perf_counter() - t3
    return Prepared(spec=spec, scene=scene, local=local, sub=sub, contact=contact, timings=timings)
