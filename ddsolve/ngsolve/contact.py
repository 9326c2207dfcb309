"""Contact of two membranes (model problem (3.1)) given as NGSolve objects, solved by ddsolve.

``contact_solve`` takes either one NGSolve mesh whose two materials are the
bodies, or two NGSolve meshes (one per body); a named contact boundary must be
a conforming interface (the bodies have the same vertices on it). It builds the
same :class:`ddsolve.scene.Scene` as a ``mesh_file`` contact spec
(:func:`ddsolve.scene.unstructured.scene_from_mesh`: every body its own copy of
the interface nodes, each body split into ``parts`` METIS subdomains), runs the
library's contact path (:func:`ddsolve.prepare`,
:func:`ddsolve.contact.run.run_contact_method`) and maps the solution back to
one first-order H1 GridFunction per body.

The problem is (3.1): find u = (u^1, u^2) minimising
J(u) = sum_k 1/2 int rho |grad u^k|^2 - int f u^k subject to u^2 - u^1 >= 0 at
the contact nodes (body 2 cannot pass below body 1), u = 0 on the Dirichlet
boundaries; lambda >= 0 is the nodal contact force, the KKT conditions are (5.5).
"""
from __future__ import annotations

import logging
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import ngsolve
import numpy as np

from ..errors import InputError, brief, check_seed, check_tolerance

log = logging.getLogger(__name__)

CONTACT_METHODS = ("active-set", "smalbe", "direct")


@dataclass(frozen=True)
class ContactResult:
    """Solution of the contact problem and its diagnostics.

    Attributes
    ----------
    gfu : tuple of two ngsolve.GridFunction
        u^1 and u^2: order-1 H1 GridFunctions, on the body's material
        (``definedon``) of the one mesh, or on each of the two meshes.
    points : ndarray, shape (n_c, 2)
        Contact nodes (the vertices of the contact boundary), in the order of the contact
        problem's pairs (``prepared.contact``, the rows of its B); no geometric order is promised.
    multipliers : ndarray, shape (n_c,)
        Contact forces lambda >= 0 (nodal forces pushing body 2 up).
    gap : ndarray, shape (n_c,)
        u^2 - u^1 at the contact nodes (>= 0, and zero where active, to the method's accuracy: of
        order 1e-9 for the iterative methods at the default rtol).
    active : ndarray of bool, shape (n_c,)
        Nodes in contact.
    iterations : int
        Total inner iterations (0 for ``method="direct"``).
    converged : bool
        The method's stopping rule met and, for the iterative methods, the result accepted by its
        KKT check: ``kkt_residual`` at most :func:`ddsolve.contact.problem.kkt_limit` (max(100 rtol,
        1e-8), at most 1e-2).
    reason : str
    energy : float
        J(u).
    kkt_residual : float
        Largest relative violation of the KKT conditions (5.5).
    u : ndarray, shape (ndof,)
        The library's solution vector (free node copies of
        ``prepared.sub``), for checks.
    prepared : ddsolve.prepared.Prepared
        The assembled, decomposed problem (``prepared.contact`` is the
        :class:`~ddsolve.contact.problem.ContactProblem`).
    timings : dict
        Seconds of ``"scene"``, ``"prepare"`` and ``"solve"``.
    """

    gfu: tuple
    points: np.ndarray
    multipliers: np.ndarray
    gap: np.ndarray
    active: np.ndarray
    iterations: int
    converged: bool
    reason: str
    energy: float
    kkt_residual: float
    u: np.ndarray
    prepared: Any
    timings: dict = field(default_factory=dict)


def _names(value: str | Sequence[str], what: str) -> Any:
    """NGSolve-style "a|b" or a sequence of names -> list of names (or "boundary")."""
    if isinstance(value, str):
        if value == "boundary":
            return "boundary"
        names = [n for n in value.split("|") if n]
    else:
        try:
            names = [str(n) for n in value]
        except TypeError:
            raise InputError(what, f"expected boundary names ('a|b' or a list), got {value!r}") from None
    if not names:
        raise InputError(what, "no boundary names given")
    return names


def _per_body(name: str, value: Any, bodies: Sequence[str]) -> list[Any]:
    """A number, a dict body name -> value, or a sequence of two values -> one value per body."""
    if isinstance(value, dict):
        unknown = sorted(set(value) - set(bodies))
        if unknown:
            raise InputError(name, f"unknown body {unknown[0]!r}; the bodies are {list(bodies)}")
        missing = [b for b in bodies if b not in value]
        if missing:
            raise InputError(name, f"no value for body {missing[0]!r}")
        return [value[b] for b in bodies]
    if isinstance(value, (list, tuple)):
        if len(value) != len(bodies):
            raise InputError(name, f"expected {len(bodies)} values (one per body), got {len(value)}")
        return list(value)
    return [value] * len(bodies)


def _reads_a_gridfunction(cf: Any) -> bool:
    """Whether a CoefficientFunction is, or is an expression of, a GridFunction (``1.0 * g``,
    ``CoefficientFunction(g)``, ``IfPos(x, g, 1)``): NGSolve names a GridFunction leaf in the expression
    tree it prints (``gridfunction '...'`` or its C++ type ``...GridFunction...``) and offers no other way
    to walk the tree from Python."""
    return isinstance(cf, ngsolve.GridFunction) or "gridfunction" in str(cf).lower()


def _number(name: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        if isinstance(value, ngsolve.CoefficientFunction) and name == "f":     # in a dict or pair of per-body loads
            raise InputError(name, "a per-body value must be a number; for a function give one "
                                   "CoefficientFunction for both bodies (e.g. with IfPos or MaterialCF)") from None
        if isinstance(value, ngsolve.CoefficientFunction):
            raise InputError(name, "must be a number, a pair of numbers or a dict of them (one per body), "
                                   "got a CoefficientFunction") from None
        raise InputError(name, f"expected a number, got {brief(value)}") from None
    if not np.isfinite(out):
        raise InputError(name, f"must be finite, got {value!r}")
    return out


def _merge_meshes(meshes: Sequence[Any], contact: str) -> Any:
    """One NetgenData of two meshes whose vertices on the ``contact`` boundary coincide (identified)."""
    from scipy.spatial import cKDTree

    from ..scene.unstructured import NetgenData, netgen_arrays

    datas = [netgen_arrays(m.ngmesh) for m in meshes]
    on = []
    for k, d in enumerate(datas):
        ids = [i for i, bc in enumerate(d.bc_names) if bc == contact]
        if not ids:
            raise InputError("contact", f"mesh {k + 1} has no boundary named {contact!r}; it has "
                                        f"{sorted(set(d.bc_names))}")
        on.append(np.unique(d.segments[np.isin(d.segment_bc, ids)]))
    c0, c1 = datas[0].coords[on[0]], datas[1].coords[on[1]]
    size = float(max(np.ptp(datas[0].coords, axis=0).max(), np.ptp(datas[1].coords, axis=0).max())) or 1.0
    tol = 1e-8 * size
    dist, idx = cKDTree(c0).query(c1)
    back, _ = cKDTree(c1).query(c0)
    bad1, bad0 = np.flatnonzero(dist > tol), np.flatnonzero(back > tol)
    if bad1.size or bad0.size:
        where, k = (c1[bad1[0]], 2) if bad1.size else (c0[bad0[0]], 1)
        raise InputError("contact", f"boundary {contact!r} is not conforming: vertex ({where[0]:.6g}, "
                                    f"{where[1]:.6g}) of mesh {k} has no coincident vertex on the other mesh "
                                    f"({bad1.size + bad0.size} such vertices); mesh the bodies so that their "
                                    f"vertices match on the contact line")
    n0 = datas[0].coords.shape[0]
    remap = np.arange(datas[1].coords.shape[0]) + n0
    remap[on[1]] = on[0][idx]
    d0, d1 = datas
    bc_names = d0.bc_names + d1.bc_names
    return NetgenData(coords=np.concatenate([d0.coords, d1.coords]),
                      elements=np.concatenate([d0.elements, remap[d1.elements]]),
                      material=np.r_[np.zeros(d0.elements.shape[0], np.int64), np.ones(d1.elements.shape[0], np.int64)],
                      segments=np.concatenate([d0.segments, remap[d1.segments]]),
                      segment_bc=np.r_[d0.segment_bc, d1.segment_bc + len(d0.bc_names)],
                      material_names=["body1", "body2"], bc_names=bc_names), [d0.elements, d1.elements]


def _load_cf(f: Any) -> Any:
    """A real scalar CoefficientFunction from ``f`` (a CoefficientFunction, or ``f(x, y)`` on NGSolve's
    coordinate functions returning one or a number)."""
    if not isinstance(f, ngsolve.CoefficientFunction):
        try:
            f = f(ngsolve.x, ngsolve.y)
        except Exception as exc:          # noqa: BLE001 - the user's callable; its error becomes one line
            raise InputError("f", f"calling f(x, y) with NGSolve's coordinates failed: {exc}") from None
        if not isinstance(f, ngsolve.CoefficientFunction):
            f = ngsolve.CoefficientFunction(_number("f", f))
    if f.is_complex:
        raise InputError("f", "must be real, got a complex CoefficientFunction")
    if f.dim != 1:
        raise InputError("f", f"must be a scalar CoefficientFunction, got one of dimension {f.dim}")
    return f


def _element_loads(f: Any, mesh: Any, elements: np.ndarray) -> np.ndarray:
    """int_e f phi_j on every triangle of ``mesh``, shape (n_elements, 3), in the vertex order of ``elements``.

    Integrated on the user's mesh, so that a CoefficientFunction that depends on it (``MaterialCF``,
    a GridFunction) means what it means there, with NGSolve's order-3 rule: its six points lie
    inside the triangle. The order-2 rule of a triangle is its three edge midpoints, and on the
    contact line a load that jumps there (``IfPos(x - 1, ...)``) was read from the other body's
    side (body 2 received 2.8% more load in the third review's case).
    """
    from .dofs import element_dofs

    cf = _load_cf(f)
    fes = ngsolve.H1(mesh, order=1)
    v = ngsolve.Discontinuous(fes).TestFunction()
    try:
        lf = ngsolve.LinearForm(cf * v * ngsolve.dx(bonus_intorder=1)).Assemble()
    except Exception as exc:           # cf * v simplified away: a load NGSolve knows to be zero (0 * x, CF(0))
        if "TestFunction" not in str(exc):
            raise
        lf = None
    b = (np.zeros((len(elements), 3)) if lf is None
         else np.array(lf.vec.FV().NumPy()).reshape(-1, 3))       # element by element, in element_dofs order
    T = element_dofs(fes)                                  # order 1: the vertex numbers
    if not np.array_equal(np.sort(T, axis=1), np.sort(elements, axis=1)):
        raise RuntimeError("the mesh's element vertices differ from netgen's element table")
    position = np.argmax(T[:, None, :] == elements[:, :, None], axis=2)
    b = np.take_along_axis(b, position, axis=1)
    if not np.all(np.isfinite(b)):
        raise InputError("f", "is not finite on the mesh (NaN or inf)")
    return b


def contact_solve(mesh: Any, bodies: Sequence[str] | None = None, *, contact: str = "contact",
                  dirichlet: str | Sequence[str] = "boundary", rho: Any = 1.0, f: Any = -1.0,
                  method: str = "active-set", parts: int = 4, rtol: float = 1e-8, maxiter: int = 1000,
                  preset: str = "default", seed: int = 0) -> ContactResult:
    """Solve the two-body contact problem (3.1) on NGSolve meshes with ddsolve's contact solvers.

    Parameters
    ----------
    mesh : ngsolve.Mesh or (ngsolve.Mesh, ngsolve.Mesh)
        One mesh whose materials ``bodies`` are the two bodies (meshed as one
        geometry so that they share their vertices on the contact line), or
        two meshes, body 1 and body 2, whose vertices on ``contact`` coincide.
    bodies : (str, str), optional
        Material names of body 1 and body 2 (one mesh; default: its two
        materials in order). Must be None for two meshes.
    contact : str
        Name of the contact boundary (a conforming interface of the bodies).
    dirichlet : "boundary", "a|b" or sequence of str
        Boundaries with u = 0 ("boundary": the whole outer boundary).
    rho : float, dict or pair
        Coefficient per body (a dict maps body names, "body1"/"body2" for two meshes).
    f : float, dict, pair, ngsolve.CoefficientFunction or callable
        Load: a number or one per body, or a real scalar CoefficientFunction on
        ``mesh`` (any: of ``x``, ``y``, ``MaterialCF``, a GridFunction; with two meshes the function is
        integrated on each, so it must be defined on both: a GridFunction of one mesh is refused), or
        ``f(x, y)`` called with NGSolve's coordinate functions ``ngsolve.x``, ``ngsolve.y``
        (CoefficientFunctions, not arrays: write ``IfPos(x - 1, a, b)``, not
        ``np.where(x > 1, a, b)``). A function is
        integrated on the user's mesh against the P1 shape functions with six
        points inside each triangle (none on the contact line).
    method : {"active-set", "smalbe", "direct"}
    parts : int
        METIS subdomains per body.
    rtol, maxiter : float, int
        Inner tolerance (active set: PCR/PCG; SMALBE: epsilon) and iteration cap.
    preset : str
        A preset of :mod:`ddsolve.presets` (``"default"`` or ``"thesis"``).
    seed : int
        METIS seed.

    Returns
    -------
    ContactResult

    Raises
    ------
    InputError
        Naming the argument: a missing material or boundary name, a
        non-conforming contact interface (with its location), bodies that share
        edges off the contact boundary, contact vertices clamped in one body
        only, a curved mesh, a floating body whose load does not press it onto
        the other, a complex, vector-valued or non-finite load, bad numbers.
    """
    from ..contact.run import contact_result_fields, run_contact_method
    from ..prepared import check_smalbe_scene, prepare
    from ..presets import solver_options
    from ..scene.contact import check_contact_load
    from ..scene.unstructured import _assemble_scene, netgen_arrays, scene_from_mesh
    from ..spec import ProblemSpec

    if method not in CONTACT_METHODS:
        raise InputError("method", f"expected one of {CONTACT_METHODS}, got {method!r}")
    if not isinstance(contact, str) or not contact:
        raise InputError("contact", f"expected a boundary name, got {contact!r}")
    if isinstance(parts, bool) or not isinstance(parts, (int, np.integer)) or parts < 1:
        raise InputError("parts", f"must be a positive integer, got {parts!r}")
    rtol = check_tolerance("rtol", rtol)       # strict, as DDInverse: "1e-8" or None was read by the spec
    if isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer)) or maxiter < 1:
        raise InputError("maxiter", f"must be a positive integer, got {brief(maxiter)}")
    seed = check_seed("seed", seed)
    for m in (mesh if isinstance(mesh, (tuple, list)) else (mesh,)):
        if isinstance(m, ngsolve.Mesh) and m.GetCurveOrder() > 1:    # the scene has straight triangles
            raise InputError("mesh", f"curved elements (mesh.Curve({m.GetCurveOrder()})) are not supported: "
                                     "the bodies are solved on straight P1 triangles; pass the uncurved mesh")
        if isinstance(m, ngsolve.Mesh) and m.deformation is not None:   # the scene reads the undeformed vertices
            raise InputError("mesh", "a mesh with SetDeformation is not supported: the bodies are solved on the "
                                     "undeformed vertices; call mesh.UnsetDeformation() or move the vertices")
    iterative = method != "direct"      # the spec refuses rtol/maxiter for a direct solve
    spec = ProblemSpec.from_mapping({"problem": "contact", "mesh": "unstructured", "method": method,
                                     "parts": int(parts), "rtol": rtol if iterative else None,
                                     "maxiter": maxiter if iterative else None, "preset": preset})
    dirichlet = _names(dirichlet, "dirichlet")
    t0 = time.perf_counter()
    two = isinstance(mesh, (tuple, list))
    if two:
        if len(mesh) != 2 or not all(isinstance(m, ngsolve.Mesh) for m in mesh):
            raise InputError("mesh", "expected one ngsolve.Mesh or a pair of them")
        if bodies is not None:
            raise InputError("bodies", "with two meshes each mesh is one body; leave bodies out")
        meshes, body_names = tuple(mesh), ["body1", "body2"]
        data, originals = _merge_meshes(meshes, contact)
        rho_b = _positive_per_body(rho, body_names)
        scene = _assemble_scene(data, np.array([0, 1]), parts=int(parts), dirichlet=dirichlet, contact=contact,
                                rho=np.repeat(rho_b, int(parts)), f=1.0, seed=seed)
        material = data.material
    else:
        if not isinstance(mesh, ngsolve.Mesh):
            raise InputError("mesh", f"expected an ngsolve.Mesh or a pair of them, got {type(mesh).__name__}")
        data = netgen_arrays(mesh.ngmesh)
        if bodies is None:
            body_names = list(dict.fromkeys(data.material_names[i] for i in np.unique(data.material)))
        elif isinstance(bodies, str) or not isinstance(bodies, (list, tuple, np.ndarray)):
            raise InputError("bodies", f"expected two material names (a pair), got {brief(bodies)}")
        else:
            body_names = [str(b) for b in bodies]
        if len(body_names) != 2:
            raise InputError("bodies", f"contact needs two bodies (materials), got {body_names}")
        if body_names[0] == body_names[1]:
            raise InputError("bodies", f"the two bodies must be two different materials, got {body_names}")
        rho_b = _positive_per_body(rho, body_names)
        scene = scene_from_mesh(mesh.ngmesh, bodies=body_names, dirichlet=dirichlet, contact=contact,
                                parts=int(parts), rho=np.repeat(rho_b, int(parts)), f=1.0, seed=seed)
        meshes = (mesh, mesh)
        originals = None
        material = np.array([body_names.index(data.material_names[m]) for m in range(len(data.material_names))
                             ])[data.material]
    el_body = scene.subdomain_body[scene.element_subdomain]
    if isinstance(f, (dict, list, tuple)):
        f_b = np.array([_number("f", v) for v in _per_body("f", f, body_names)])
        scene.f = f_b[el_body]
    elif isinstance(f, ngsolve.CoefficientFunction) or callable(f):
        if two:
            if isinstance(f, ngsolve.CoefficientFunction) and _reads_a_gridfunction(f):
                raise InputError("f", "reads a GridFunction, which lives on one mesh and which NGSolve reads as 0 "
                                      "on the other body's mesh; give a CoefficientFunction of x, y, a number per "
                                      "body, or the bodies as one mesh")
            scene.f = np.concatenate([_element_loads(f, m, els) for m, els in zip(meshes, originals)])
        else:
            scene.f = _element_loads(f, mesh, data.elements)
    else:
        scene.f = _number("f", f)
    floating = check_contact_load(scene, scene.f, body_names)
    if method == "smalbe":
        check_smalbe_scene(floating)
    t1 = time.perf_counter()
    prep = prepare(spec, scene=scene)
    t2 = time.perf_counter()
    problem = prep.contact
    sol = run_contact_method(method, problem, rtol=float(spec.rtol), maxiter=int(spec.maxiter),
                             **solver_options(spec.preset, "contact", method))
    fields = contact_result_fields(spec, problem, sol)
    t3 = time.perf_counter()

    sub = prep.sub
    u_node = np.zeros(scene.n_nodes)
    free = sub.dof_of_node >= 0
    u_node[free] = sol.u[sub.dof_of_node[free]]
    gfus = []
    for k in range(2):
        if two:
            fes = ngsolve.H1(meshes[k], order=1)
            mine = np.flatnonzero(data.material == k)
            original = originals[k]
        else:
            fes = ngsolve.H1(mesh, order=1, definedon=mesh.Materials("^" + re.escape(body_names[k]) + "$"))
            mine = np.flatnonzero(material == k)
            original = data.elements[mine]
        gfu = ngsolve.GridFunction(fes, name=f"u{k + 1}")
        vec = gfu.vec.FV().NumPy()
        vec[original.ravel()] = u_node[scene.elements[mine].ravel()]
        gfus.append(gfu)
    pairs = problem.gi.pair_nodes
    result = ContactResult(gfu=tuple(gfus), points=scene.coords[pairs[:, 0]].copy(), multipliers=sol.lam.copy(),
                           gap=-problem.gap(sol.u), active=np.asarray(sol.active, dtype=bool).copy(),
                           iterations=int(fields["iterations"]), converged=bool(fields["converged"]),
                           reason=fields["reason"], energy=float(fields["extra"]["energy"]),
                           kkt_residual=float(fields["extra"]["kkt_residual"]), u=sol.u, prepared=prep,
                           timings={"scene": t1 - t0, "prepare": t2 - t1, "solve": t3 - t2})
    log.info("contact_solve %s: %s, %d iterations, KKT %.1e", method, result.reason, result.iterations,
             result.kkt_residual)
    return result


def _positive_per_body(rho: Any, body_names: Sequence[str]) -> list[float]:
    """One positive coefficient per body (checked before the scene is built, whose check counts subdomains)."""
    rho_b = [_number("rho", r) for r in _per_body("rho", rho, body_names)]
    if not all(r > 0 for r in rho_b):
        raise InputError("rho", f"must be positive, got {rho_b}")
    return rho_b
