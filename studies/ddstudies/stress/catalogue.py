"""Stress study, the catalogue: :class:`StressCase` and :func:`catalog` (the cases of a tier).

The package :mod:`ddstudies.stress`: catalogue (here), :mod:`~ddstudies.stress.runner`,
:mod:`~ddstudies.stress.criteria` and :mod:`~ddstudies.stress.render` (Markdown and JSON).

Each :class:`StressCase` states in one line what it proves (``claim``) and is
judged by one rule of :data:`CRITERIA` (``criterion``). :func:`run_case` solves
it and returns a flat, JSON-serialisable record (iterations, condition
estimate, true and recursive relative residual, error against the direct
solver, ...); it never raises: an exception becomes ``status = "crash"``, an
expected :class:`~ddsolve.errors.InputError` ``status = "input_error"``, a case
that exceeds its wall-clock limit ``status = "timeout"``. :func:`evaluate`
applies the criteria (some compare with a baseline case, e.g. the iterations
at rho = 1) and :func:`render_markdown` writes the report, one row per case.

Groups (the catalog of :func:`catalog`, tier ``"study"`` for the Snakemake
study ``config/stress.yaml``, tier ``"quick"`` for ``tests/test_stress.py``):

``jumps``
    Checkerboard coefficients rho in {1e-6, ..., 1e6} across subdomains (for
    the multibody problem across the subdomains of all bodies, and across
    bodies with ``"body-checkerboard:V"``), rho-scaling against multiplicity
    scaling, for FETI-DP, BDDC, one-level FETI, FETI-FETI and the hybrid method
    (the latter in its robust configuration :data:`HYBRID_JUMP_OPTIONS`).
``tolerance``
    Relative tolerances down to 1e-12: convergence without stagnation and a
    recomputed (true) residual within a factor 10 of the recursive one.
``scale``
    Many subdomains, large H/h, many floating bodies, each against a smaller
    baseline.
``contact``
    Problem (3.1) with extreme loads: none on the floating membrane (an
    input error), full contact, a contact zone of one node, a floating body
    barely pressed on (net load -1e-8) and a net load at round-off level; the
    active set, SMALBE and direct methods must agree or fail cleanly.
``degenerate``
    Tolerances that cannot be met (too few iterations, below round-off) and
    one-subdomain decompositions.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ddsolve.errors import InputError

__all__ = ["StressCase", "GROUPS", "JUMPS", "HYBRID_JUMP_OPTIONS", "catalog", "contact_load"]

#: Report sections, in order.
GROUPS: dict[str, str] = {
    "jumps": "Coefficient jumps: rho-scaling against multiplicity scaling",
    "tolerance": "Tight tolerances",
    "scale": "Many subdomains, large H/h, many floating bodies",
    "contact": "Contact extremes (problem (3.1))",
    "degenerate": "Degenerate input",
}
#: Checkerboard values of the jump study.
JUMPS: tuple[float, ...] = (1e-6, 1e-4, 1e-2, 1.0, 1e2, 1e4, 1e6)

#: Poisson methods with a Lanczos condition estimate.
_COND_METHODS = ("feti", "fetidp", "bddc", "feti-feti")


@dataclass(frozen=True)
class StressCase:
    """One stress case.

    Attributes
    ----------
    name : str
        Unique id (letters, digits, ``._-``).
    group : str
        Key of :data:`GROUPS`.
    series : str
        Cases of one series run in one Snakemake job (``results/<study>/cases/<series>.json``).
    claim : str
        One line: what the case proves.
    criterion : str
        Key of :data:`CRITERIA`.
    spec : dict
        :class:`~ddsolve.spec.ProblemSpec` mapping.
    runner : {"api", "contact"}
        ``"api"``: :func:`ddsolve.solve`. ``"contact"``: the contact problem of
        ``spec`` (or of the per-element ``load``) solved by its method and by the
        direct reference (:func:`ddsolve.contact.run.run_contact_method`).
    load : str, optional
        Named per-element contact load (:func:`contact_load`).
    baseline : str, optional
        Name of the case compared with (iterations, condition estimate).
    expect_message : str, optional
        ``input_error``: a substring of the expected message.
    expect_active : str, optional
        ``contact_reference``: ``"all"`` or ``"1"``, the contact zone the load is designed for.
    """

    name: str
    group: str
    series: str
    claim: str
    criterion: str
    spec: Mapping[str, Any]
    runner: str = "api"
    load: str | None = None
    baseline: str | None = None
    expect_message: str | None = None
    expect_active: str | None = None


# --------------------------------------------------------------------------- #
# The catalog
# --------------------------------------------------------------------------- #
#: Problem sizes of the two tiers.
_TIERS: dict[str, dict[str, Any]] = {
    "study": {
        "poisson": (4, 8), "multibody": (4, 2, 4), "contact": (8, 8),
        "many_sub": ((4, 4), (32, 4)), "large_Hh": ((2, 16), (2, 256)),
        "mb_many_sub": ((2, 4, 2), (2, 32, 2)), "mb_floating": ((2, 2, 4), (8, 2, 4)),
        "mb_large_Hh": ((2, 2, 16), (2, 2, 256)),
        "tolerances": (1e-8, 1e-10, 1e-12),
    },
    "quick": {
        "poisson": (4, 4), "multibody": (4, 2, 2), "contact": (4, 4),
        "many_sub": ((4, 2), (16, 2)), "large_Hh": ((2, 4), (2, 64)),
        "mb_many_sub": ((2, 2, 2), (2, 8, 2)), "mb_floating": ((2, 2, 2), (4, 2, 2)),
        "mb_large_Hh": ((2, 2, 4), (2, 2, 32)),
        "tolerances": (1e-12,),
    },
}


def _fmt(value: float) -> str:
    """1e-06 -> '1e-06', 1.0 -> '1', 100.0 -> '1e+02' (file-name safe)."""
    return "1" if value == 1.0 else f"{value:.0e}"


def catalog(tier: str = "study") -> list[StressCase]:
    """All stress cases of a tier.

    Parameters
    ----------
    tier : {"study", "quick"}
        ``"study"``: the sizes of the Snakemake study (32 x 32 subdomains, H/h =
        256, 1/H_b = 8); ``"quick"``: smaller versions of the same cases for
        the test suite.

    Returns
    -------
    list of StressCase
        Unique names; baselines precede the cases that refer to them.

    Raises
    ------
    InputError
        For an unknown tier.
    """
    if tier not in _TIERS:
        raise InputError("tier", f"unknown stress tier {tier!r} (choose from {', '.join(_TIERS)})")
    t = _TIERS[tier]
    cases: list[StressCase] = []
    cases += _jump_cases(t)
    cases += _tolerance_cases(t)
    cases += _scale_cases(t)
    cases += _contact_cases(t)
    cases += _degenerate_cases(t)
    names = [c.name for c in cases]
    if len(set(names)) != len(names):  # pragma: no cover - catalog invariant
        raise RuntimeError("duplicate stress case names")
    return cases


#: The hybrid method's options in the jump study: PCR stops on ||r||_M (M the preconditioner
#: (4.11)) and projects onto ker(G^T) with the rho-weighted super-lumped Q (see
#: :meth:`ddsolve.multibody.hybrid.HybridSolver.solve`). The thesis's ||r||_2 and orthogonal
#: P^k need up to 3.5x the iterations of rho = 1 when bodies float.
HYBRID_JUMP_OPTIONS: dict[str, str] = {"norm": "M", "projection": "lumped"}


def _jump_cases(t: Mapping[str, Any]) -> list[StressCase]:
    ns, m = t["poisson"]
    nb, nsb, mb = t["multibody"]
    families = [(meth, "checkerboard", {"method": meth, "subdomains": ns, "elements": m, "f": "random:0"},
                 f"poisson {ns}x{ns} subdomains, H/h={m}")
                for meth in ("fetidp", "bddc", "feti")]
    for pattern in ("checkerboard", "body-checkerboard"):
        where = "subdomains of all bodies" if pattern == "checkerboard" else "bodies"
        families += [(meth, pattern, {"problem": "multibody", "method": meth, "bodies": nb, "subdomains": nsb,
                                      "elements": mb, "contact": "full",
                                      **(HYBRID_JUMP_OPTIONS if meth == "hybrid" else {})},
                      f"multibody {nb}x{nb} bodies of {nsb}x{nsb} subdomains, H/h={mb}, jumps across {where}"
                      + (", ||r||_M, lumped projection" if meth == "hybrid" else ""))
                     for meth in ("feti-feti", "hybrid")]
    out = []
    for meth, pattern, base, where in families:
        short = "body" if pattern == "body-checkerboard" else "cb"
        for scaling in ("rho", "multiplicity"):
            series = f"jumps_{meth}_{short}_{scaling}"
            ref = f"{series}_1"
            for value in JUMPS:
                name = f"{series}_{_fmt(value)}"
                spec = {**base, "rho": f"{pattern}:{value:g}", "scaling": scaling,
                        "cond": meth in _COND_METHODS, "check": True}
                if value == 1.0:
                    claim, criterion, baseline = (f"{meth} ({scaling} scaling), rho = 1: reference iterations "
                                                  f"for the jumps ({where})", "accurate", None)
                elif scaling == "rho":
                    claim, criterion, baseline = (f"{meth}: rho-scaling is robust for a {pattern} jump "
                                                  f"{value:.0e} ({where})", "robust", ref)
                else:
                    claim, criterion, baseline = (f"{meth}: multiplicity scaling is not robust for a "
                                                  f"{pattern} jump {value:.0e}, as theory predicts ({where})",
                                                  "not_robust", ref)
                out.append(StressCase(name, "jumps", series, claim, criterion, spec, baseline=baseline))
    return out


def _tolerance_cases(t: Mapping[str, Any]) -> list[StressCase]:
    ns, m = t["poisson"]
    nb, nsb, mb = t["multibody"]
    out = []
    for meth in ("fetidp", "bddc", "feti"):
        series = f"tolerance_{meth}"
        for rtol in t["tolerances"]:
            spec = {"method": meth, "subdomains": ns, "elements": m, "f": "random:0", "rho": "checkerboard:1e4",
                    "scaling": "multiplicity", "rtol": rtol, "maxiter": 500, "cond": True, "check": True}
            out.append(StressCase(f"{series}_{_fmt(rtol)}", "tolerance", series,
                                  f"{meth} (PCG) reaches rtol {rtol:.0e} at a large condition number (1e4 "
                                  f"checkerboard, multiplicity scaling) without stagnation; recursive and true "
                                  f"residual agree", "accurate", spec))
    for meth in ("feti-feti", "hybrid"):
        for contact in ("full", "middle"):
            series = f"tolerance_{meth}_{contact}"
            solver = "PCG" if meth == "feti-feti" else "PCR, restarted on drift"
            for rtol in t["tolerances"]:
                spec = {"problem": "multibody", "method": meth, "bodies": nb, "subdomains": nsb, "elements": mb,
                        "contact": contact, "rtol": rtol, "maxiter": 1000, "cond": meth == "feti-feti",
                        "check": True}
                out.append(StressCase(f"{series}_{_fmt(rtol)}", "tolerance", series,
                                      f"{meth} ({solver}), contact {contact}, floating bodies: rtol {rtol:.0e} "
                                      f"without stagnation; recursive and true residual agree", "accurate", spec))
    return out


def _scale_cases(t: Mapping[str, Any]) -> list[StressCase]:
    out = []
    (ns0, m0), (ns1, m1) = t["many_sub"]
    for meth in ("fetidp", "bddc", "feti"):
        series = f"scale_subdomains_{meth}"
        common = {"method": meth, "f": "random:0", "cond": True, "check": True}
        base = f"{series}_N{ns0}"
        out.append(StressCase(base, "scale", series, f"{meth}: baseline {ns0}x{ns0} subdomains, H/h={m0}",
                              "accurate", {**common, "subdomains": ns0, "elements": m0}))
        out.append(StressCase(f"{series}_N{ns1}", "scale", series,
                              f"{meth}: iterations independent of the number of subdomains "
                              f"({ns1}x{ns1} = {ns1 * ns1} subdomains)", "scalable",
                              {**common, "subdomains": ns1, "elements": m1}, baseline=base))
    (ns0, m0), (ns1, m1) = t["large_Hh"]
    for meth in ("fetidp", "bddc", "feti"):
        series = f"scale_Hh_{meth}"
        common = {"method": meth, "f": "random:0", "cond": True, "check": True}
        base = f"{series}_m{m0}"
        out.append(StressCase(base, "scale", series, f"{meth}: baseline H/h = {m0}, {ns0}x{ns0} subdomains",
                              "accurate", {**common, "subdomains": ns0, "elements": m0}))
        out.append(StressCase(f"{series}_m{m1}", "scale", series,
                              f"{meth}: cond grows at most like (1 + log H/h)^2 up to H/h = {m1}", "polylog",
                              {**common, "subdomains": ns0, "elements": m1}, baseline=base))
    for key, what in (("mb_many_sub", "subdomains per body"), ("mb_floating", "floating bodies"),
                      ("mb_large_Hh", "H_s/h")):
        small, large = t[key]
        for meth in ("feti-feti", "hybrid"):
            series = f"scale_{key}_{meth}"
            common = {"problem": "multibody", "method": meth, "contact": "full", "cond": meth == "feti-feti",
                      "check": True}
            for size, role in ((small, "baseline"), (large, "large")):
                nb, nsb, mb = size
                floating = max(nb - 2, 0) ** 2
                label = (f"1/H_b={nb} ({floating} floating), H_b/H_s={nsb} ({nsb}x{nsb} subdomains per body), "
                         f"H_s/h={mb}")
                claim = (f"{meth}: baseline {label}" if role == "baseline"
                         else f"{meth}: converges accurately with many {what}: {label}")
                out.append(StressCase(f"{series}_{nb}_{nsb}_{mb}", "scale", series, claim, "accurate",
                                      {**common, "bodies": nb, "subdomains": nsb, "elements": mb}))
    return out


def _contact_cases(t: Mapping[str, Any]) -> list[StressCase]:
    ns, m = t["contact"]
    base = {"problem": "contact", "subdomains": ns, "elements": m}
    out = [
        StressCase("contact_noload_positive", "contact", "contact_noload",
                   "f = 1 (integral over Omega^2 > 0) cannot keep the floating membrane in contact: "
                   "one-line input error", "input_error", {**base, "method": "active-set", "f": 1.0},
                   expect_message="negative integral"),
        StressCase("contact_noload_unloaded", "contact", "contact_noload",
                   "Omega^2 unloaded (integral of f = 0): one-line input error", "input_error",
                   {**base, "method": "smalbe"}, runner="contact", load="unloaded",
                   expect_message="negative integral"),
    ]
    loads = [
        ("full_uniform", None, -1.0, "all", "full contact, f = -1 on both membranes (every pair active)"),
        ("full", "full", None, "all", "full contact, Omega^1 pushed up, Omega^2 down with a y-varying load"),
        ("single_node", "single-node", None, "1",
         "contact zone of a single node (concentrated upward load on Omega^1 at (1, 1/2))"),
        ("barely", "barely:1e-8", None, None,
         "Omega^2 barely pressed on: self-balanced load with net -1e-8"),
        ("roundoff", "barely:1e-15", None, None,
         "net load -1e-15, at round-off level of the self-balanced load: rejected as input, or resolved"),
    ]
    for key, load, f, active, what in loads:
        series = f"contact_{key}"
        spec = {**base, **({"f": f} if f is not None else {})}
        for meth in ("direct", "active-set", "smalbe"):
            if meth == "direct":
                claim = f"{what}: the direct reference solves it (KKT, force balance, contact zone)"
                criterion = "contact_reference"
            else:
                claim = f"{what}: {meth} agrees with direct or fails cleanly"
                criterion = "contact_agree"
            out.append(StressCase(f"{series}_{meth}", "contact", series, claim, criterion,
                                  {**spec, "method": meth}, runner="contact", load=load,
                                  expect_active=active if meth == "direct" else None,
                                  expect_message="negative integral" if key == "roundoff" else None))
    return out


def _degenerate_cases(t: Mapping[str, Any]) -> list[StressCase]:
    ns, m = t["poisson"]
    nb, nsb, mb = t["multibody"]
    cs, cm = t["contact"]
    problems = {
        "fetidp": {"method": "fetidp", "subdomains": ns, "elements": m, "f": "random:0"},
        "bddc": {"method": "bddc", "subdomains": ns, "elements": m, "f": "random:0"},
        "feti": {"method": "feti", "subdomains": ns, "elements": m, "f": "random:0"},
        "feti-feti": {"problem": "multibody", "method": "feti-feti", "bodies": nb, "subdomains": nsb,
                      "elements": mb},
        "hybrid": {"problem": "multibody", "method": "hybrid", "bodies": nb, "subdomains": nsb, "elements": mb},
        "active-set": {"problem": "contact", "method": "active-set", "subdomains": cs, "elements": cm},
        "smalbe": {"problem": "contact", "method": "smalbe", "subdomains": cs, "elements": cm},
    }
    out = []
    for meth, spec in problems.items():
        flags = {"cond": meth in _COND_METHODS, "check": True}
        out.append(StressCase(f"degenerate_maxiter_{meth}", "degenerate", "degenerate_maxiter",
                              f"{meth}: rtol 1e-10 in at most 3 iterations cannot be met: converged=False "
                              f"with a reason", "not_converged", {**spec, **flags, "rtol": 1e-10, "maxiter": 3}))
        out.append(StressCase(f"degenerate_roundoff_{meth}", "degenerate", "degenerate_roundoff",
                              f"{meth}: rtol 1e-20 is below round-off: converged=False with a reason "
                              f"(no false convergence, no hang)", "not_converged",
                              {**spec, **flags, "rtol": 1e-20, "maxiter": 300}))
    one = [("poisson_fetidp", {"method": "fetidp", "subdomains": 1, "elements": m}),
           ("multibody_feti-feti", {"problem": "multibody", "method": "feti-feti", "bodies": 3,
                                    "subdomains": 1, "elements": mb}),
           ("multibody_hybrid", {"problem": "multibody", "method": "hybrid", "bodies": 3, "subdomains": 1,
                                 "elements": mb}),
           ("contact_active-set", {"problem": "contact", "method": "active-set", "subdomains": 1,
                                   "elements": cm}),
           ("contact_smalbe", {"problem": "contact", "method": "smalbe", "subdomains": 1, "elements": cm})]
    for key, spec in one:
        out.append(StressCase(f"degenerate_onesub_{key}", "degenerate", "degenerate_onesub",
                              f"{spec['method']} on one subdomain per body side (no interface / a floating "
                              f"body without a primal vertex): one-line input error, no crash",
                              "input_error", spec, expect_message="subdomains:"))
    return out


# --------------------------------------------------------------------------- #
# Contact loads
# --------------------------------------------------------------------------- #
def contact_load(name: str, subdomains: int, elements: int) -> np.ndarray:
    """Per-element load of a named contact stress case on ``two_membranes(subdomains, elements)``.

    Parameters
    ----------
    name : str
        ``"full"``: f = 1 on Omega^1 (pushed up), f = -2 + cos(pi y) on Omega^2
        (pushed down): every contact pair is active. ``"single-node"``: a total
        upward load 30 on the two Omega^1 elements at the node (1, 1/2), f = -1
        on Omega^2: the contact zone is that node (needs an even number of
        elements per side). ``"barely:EPS"``: f = cos(2 pi y) on Omega^1 and a
        self-balanced cos(pi y) sin(pi (x - 1)) on Omega^2 shifted so that its
        integral is -EPS: Omega^2 is barely pressed on. ``"unloaded"``: f = -1
        on Omega^1, f = 0 on Omega^2 (not pressed on at all: an input error).
    subdomains, elements : int
        N = 1/H and m = H/h of the scene.

    Returns
    -------
    ndarray, shape (2 (N m)^2,)
        Element loads in the element order of :func:`ddsolve.scene.contact.two_membranes`.

    Raises
    ------
    InputError
        Unknown name, or ``"single-node"`` with an odd number of elements per side.
    """
    from ddsolve.scene.structured import body_grid

    ns, m = int(subdomains), int(elements)
    h = 1.0 / (ns * m)
    # same geometry as two_membranes (which validates the load we return)
    scene = body_grid(2, 1, ns, m, h=h, dirichlet_sides=("left",))
    c = scene.coords[scene.elements].mean(axis=1)
    x, y = c[:, 0], c[:, 1]
    on2 = x > 1.0
    f = np.zeros(x.size)
    kind, _, arg = name.partition(":")
    if kind == "full":
        f[~on2] = 1.0
        f[on2] = -2.0 + np.cos(np.pi * y[on2])
    elif kind == "single-node":
        if (ns * m) % 2:
            raise InputError("elements", f"the single-node load needs an even number of elements per side, "
                                         f"got {ns * m}")
        near = ~on2 & (np.abs(x - 1.0) < h) & (np.abs(y - 0.5) < h)   # the two elements at (1, 1/2)
        f[near] = 30.0 / (near.sum() * h * h)
        f[on2] = -1.0
    elif kind == "barely":
        try:
            eps = float(arg)
        except ValueError:
            raise InputError("load", f"'barely:EPS' needs a number, got {name!r}") from None
        f[~on2] = np.cos(2.0 * np.pi * y[~on2])
        g = np.cos(np.pi * y[on2]) * np.sin(np.pi * (x[on2] - 1.0))
        f[on2] = g - g.mean() - eps          # Omega^2 has area 1: integral = -eps (up to round-off)
    elif kind == "unloaded":
        f[~on2] = -1.0
    else:
        raise InputError("load", f"unknown contact stress load {name!r}")
    return f
