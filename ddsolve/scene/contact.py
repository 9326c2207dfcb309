"""The two-membrane contact scene of model problem (3.1), and the checks of any contact scene.

Omega^1 = (0, 1)^2 is clamped on x = 0; Omega^2 = (1, 2) x (0, 1) floats. Both
bodies are split into N x N square subdomains (1/H = N) of m x m Q1 elements
(H/h = m), so h = 1/(N m). The contact interface Gamma_c = {1} x [0, 1] carries
N m + 1 matching node pairs (the non-penetration condition u^2 - u^1 >= 0 acts
at matching nodes); the free dofs number 2 (N m + 1)^2 - (N m + 1), e.g. 561 for
N = m = 4.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import InputError
from .scene import Scene, triangle_areas
from .structured import body_grid

#: Load patches of the semicoercive benchmark of Dostal et al. (the thesis's
#: references [15, 16]): f = F1 on (0, 1) x [0.75, 1), f = F2 on (1, 2) x (0, 0.25).
DOSTAL_LOADS = (-3.0, -1.0)
#: The net load on Omega^2 must be below -NET_LOAD_FLOOR times the integral of |f| there:
#: a net force at round-off level cannot be resolved by any solver (direct included).
NET_LOAD_FLOOR = 1e-10


def dostal_loads(centroids: np.ndarray, f1: float = DOSTAL_LOADS[0], f2: float = DOSTAL_LOADS[1]) -> np.ndarray:
    """Element loads of the benchmark right-hand side.

    Parameters
    ----------
    centroids : ndarray, shape (n_elements, 2)
        Element centroids.
    f1, f2 : float
        Loads on the patches (0, 1) x [0.75, 1) and (1, 2) x (0, 0.25).

    Returns
    -------
    ndarray, shape (n_elements,)
        Element-wise constant f (exact whenever the patch edges y = 0.75 and
        y = 0.25 are mesh lines, i.e. when 4 divides N m).
    """
    x, y = centroids[:, 0], centroids[:, 1]
    out = np.zeros(centroids.shape[0])
    out[(x < 1.0) & (y >= 0.75)] = f1
    out[(x > 1.0) & (y < 0.25)] = f2
    return out


def two_membranes(subdomains: int, elements: int, *, f: float | np.ndarray | None = None,
                  rho: float | np.ndarray = 1.0, patches: tuple[float, float] = DOSTAL_LOADS) -> Scene:
    """Scene of model problem (3.1).

    Parameters
    ----------
    subdomains : int
        N = 1/H, subdomains per body side.
    elements : int
        m = H/h, Q1 elements per subdomain side.
    f : float or ndarray of shape (n_elements,), optional
        Right-hand side; None gives :func:`dostal_loads` with the patch loads
        ``patches``.
    rho : float or ndarray, shape (2 N^2,)
        Coefficient per subdomain.

    Returns
    -------
    Scene
        Bodies 0 (Omega^1) and 1 (Omega^2); ``contact_pairs[k] = (a, b)`` with
        a on Omega^1 and b on Omega^2, ordered by y.

    Raises
    ------
    InputError
        If the load on Omega^2 does not have a negative integral (below
        -:data:`NET_LOAD_FLOOR` times the integral of |f| on Omega^2): the
        floating membrane is then not pressed onto Omega^1 and (3.1) has no
        unique solution.
    """
    for name, value in (("subdomains", subdomains), ("elements", elements)):
        if int(value) != value or value < 1:
            raise InputError(name, f"must be a positive integer, got {value!r}")
    ns, m = int(subdomains), int(elements)
    scene = body_grid(2, 1, ns, m, h=1.0 / (ns * m), rho=rho, dirichlet_sides=("left",))
    centroids = scene.coords[scene.elements].mean(axis=1)
    if f is None:
        loads = dostal_loads(centroids, *patches)
    else:
        loads = np.broadcast_to(np.asarray(f, dtype=float), (scene.elements.shape[0],)).copy()
    if not np.all(np.isfinite(loads)):
        raise InputError("f", "must be finite on every element")
    on2 = scene.subdomain_body[scene.element_subdomain] == 1
    area = (1.0 / (ns * m)) ** 2
    with np.errstate(over="ignore"):        # an overflowing sum is refused below, in one line
        integral = float(loads[on2].sum() * area)
        magnitude = float(np.abs(loads[on2]).sum() * area)
    if not np.isfinite(magnitude):
        raise InputError("f", f"the load's integral over Omega^2 overflows (|f| up to "
                              f"{float(np.abs(loads).max()):.3g}); scale the load down (the solution scales with it)")
    if not integral < -NET_LOAD_FLOOR * magnitude:
        need = (f"need < -{NET_LOAD_FLOOR:g} x integral of |f| = {-NET_LOAD_FLOOR * magnitude:.3g}" if magnitude > 0
                else "the load is zero there")           # not "need < ... = -0"
        raise InputError("f", f"the floating membrane Omega^2 needs a load with negative integral "
                              f"(got {integral + 0.0:.6g}, {need}); otherwise it is not pressed onto Omega^1 "
                              f"(or only by a round-off-sized force) and (3.1) has no unique solution")
    scene.f = loads
    return scene


def floating_bodies(scene: Scene) -> list[bool]:
    """Whether each body of a contact scene floats (has no Dirichlet node), shape (n_bodies,)."""
    el_body = scene.subdomain_body[scene.element_subdomain]
    touches = np.zeros(scene.n_bodies, dtype=bool)
    node_dirichlet = scene.dirichlet[scene.elements].any(axis=1)          # elements with a Dirichlet node
    touches[np.unique(el_body[node_dirichlet])] = True
    return [not bool(t) for t in touches]


def check_contact_load(scene: Scene, loads: float | np.ndarray, body_names: Sequence[str] | None = None) -> list[bool]:
    """A floating body must be pressed onto the other (see :func:`ddsolve.scene.contact.two_membranes`).

    Body 2 (Omega^2, above) by a load with negative integral, body 1 by one with a positive
    integral; a clamped body takes any load. Both bodies floating is refused (``dirichlet``).

    Parameters
    ----------
    scene : Scene
    loads : float or ndarray, shape (n_elements,) or (n_elements, 3)
        A constant load, element-wise constant loads, or element load vectors int_e f phi_j (their
        sum is int_e f).
    body_names : (str, str), optional
        Names for the messages (:func:`ddsolve.ngsolve.contact_solve`); else Omega^1, Omega^2.

    Returns
    -------
    list of bool
        Whether body 1 and body 2 float (:func:`floating_bodies`).
    """
    loads = np.asarray(loads, dtype=float)
    if loads.ndim == 0:
        loads = np.full(scene.elements.shape[0], float(loads))
    if not np.all(np.isfinite(loads)):
        raise InputError("f", "must be finite on every element")
    floating = floating_bodies(scene)
    if all(floating):
        raise InputError("dirichlet", "both bodies float (no u = 0 boundary on either); clamp at least one")
    el_body = scene.subdomain_body[scene.element_subdomain]
    if loads.ndim == 1:
        areas = triangle_areas(scene.coords, scene.elements)
        integrals, magnitudes = loads * areas, np.abs(loads) * areas
    else:
        integrals, magnitudes = loads.sum(axis=1), np.abs(loads).sum(axis=1)
    for body in np.flatnonzero(floating):
        on = el_body == body
        integral, magnitude = float(np.sum(integrals[on])), float(np.sum(magnitudes[on]))
        sign, want, me, other = (-1.0, "negative", 2, 1) if body == 1 else (1.0, "positive", 1, 2)
        if not sign * integral > NET_LOAD_FLOOR * magnitude:     # else (3.1) has no unique solution
            if body_names is None:
                raise InputError("f", f"the floating membrane Omega^{me} needs a load with {want} integral (got "
                                      f"{integral:.6g}) to be pressed onto Omega^{other}")
            raise InputError("f", f"body {me} ({body_names[body]!r}) floats and needs a load with {want} integral "
                                  f"(got {integral:.6g}) to be pressed onto the other body")
    return floating
