"""Numerical stability stress tests: the case catalog, the runner and the report.

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

import contextlib
import json
import logging
import math
import os
import re
import signal
import threading
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)

__all__ = ["StressCase", "CRITERIA", "GROUPS", "JUMPS", "catalog", "contact_load", "run_case",
           "evaluate", "render_markdown", "write_records", "read_records"]

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
#: Iterations under rho-scaling may exceed those at rho = 1 by at most this factor.
ROBUST_FACTOR = 1.5
#: Multiplicity scaling counts as "not robust" beyond ROBUST_FACTOR x the iterations
#: or this factor x the condition estimate of rho = 1.
COND_GROWTH = 10.0
#: Converged iterative solves: error_vs_direct <= ERROR_FACTOR * rtol.
ERROR_FACTOR = 100.0
#: The recomputed residual may exceed max(recursive residual, rtol) by at most this factor.
TRUE_FACTOR = 10.0
#: The direct contact reference: KKT residual and relative force-balance error bounds.
REFERENCE_KKT = 1e-10
REFERENCE_FORCE = 1e-4

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
    from ..scene.structured import body_grid

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


# --------------------------------------------------------------------------- #
# Running one case
# --------------------------------------------------------------------------- #
class _Timeout(Exception):
    """Raised inside a case that exceeds its wall-clock limit."""


@contextlib.contextmanager
def _deadline(seconds: float | None) -> Iterator[None]:
    """Raise :class:`_Timeout` after ``seconds`` (SIGALRM; a no-op off the main thread or on Windows)."""
    usable = (seconds is not None and seconds > 0 and hasattr(signal, "SIGALRM")
              and threading.current_thread() is threading.main_thread())
    if not usable:
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise _Timeout(f"no result after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


def _finite(value: Any) -> bool:
    if value is None:
        return True
    arr = np.asarray(value, dtype=float)
    return bool(np.all(np.isfinite(arr)))


def _clean(value: Any) -> Any:
    """JSON-safe scalar: numpy -> Python, non-finite floats -> None."""
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(float(value)) else None
    return value


def _restarts(reason: str) -> int:
    match = re.search(r"after (\d+) restart", reason or "")
    return int(match.group(1)) if match else 0


def run_case(case: StressCase, *, timeout: float | None = None) -> dict[str, Any]:
    """Solve one case; never raises.

    Parameters
    ----------
    case : StressCase
    timeout : float, optional
        Wall-clock limit in seconds (main thread only); exceeding it gives
        ``status = "timeout"``.

    Returns
    -------
    dict
        Flat JSON-serialisable record: the case fields, ``status`` ("ok",
        "input_error", "crash", "timeout"), ``error`` (message of an
        exception), ``converged``, ``reason``, ``iterations``, ``cond``,
        ``rtol``, ``true_rel`` and ``rec_rel`` (true and recursive residual
        relative to ||r_0||), ``error_vs_direct``, ``nonfinite`` (names of
        quantities that came back NaN/inf), ``restarts``, ``seconds``, and for
        contact cases ``lambda_error``, ``force_error``, ``n_active``,
        ``n_active_direct``, ``n_contact``, ``kkt``, ``smalbe_gradient``.
    """
    from ..spec import ProblemSpec

    record: dict[str, Any] = {**asdict(case), "spec": dict(case.spec), "status": "ok", "error": "",
                              "converged": None, "reason": "", "iterations": None, "cond": None,
                              "rtol": None, "true_rel": None, "rec_rel": None, "error_vs_direct": None,
                              "nonfinite": [], "restarts": 0, "seconds": 0.0}
    t0 = time.perf_counter()
    try:
        with _deadline(timeout):
            spec = ProblemSpec.from_mapping(case.spec)
            record["rtol"] = float(spec.rtol)
            if case.runner == "contact":
                _run_contact(case, spec, record)
            else:
                _run_api(spec, record)
    except InputError as exc:
        record["status"], record["error"] = "input_error", str(exc)
    except _Timeout as exc:
        record["status"], record["error"] = "timeout", str(exc)
    except Exception as exc:  # noqa: BLE001 - a crash is a result here
        record["status"] = "crash"
        record["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0] if str(exc) else type(exc).__name__
        log.error("stress case %s crashed:\n%s", case.name, traceback.format_exc())
    record["seconds"] = time.perf_counter() - t0
    log.info("stress case %s: %s %s", case.name, record["status"], record["reason"] or record["error"])
    return {key: ([_clean(v) for v in val] if isinstance(val, list) else _clean(val))
            for key, val in record.items()}


def _run_api(spec: Any, record: dict[str, Any]) -> None:
    from ..api import solve

    res = solve(spec)
    r = np.asarray(res.residuals, dtype=float)
    checks = {"u": res.u, "residuals": r, "cond": res.cond, "true_residual": res.true_residual,
              "error_vs_direct": res.error_vs_direct}
    record["nonfinite"] = [k for k, v in checks.items() if not _finite(v)]
    r0 = float(r[0]) if r.size else 0.0
    record.update(converged=bool(res.converged), reason=res.reason, iterations=int(res.iterations),
                  cond=res.cond, error_vs_direct=res.error_vs_direct, restarts=_restarts(res.reason))
    if r0 > 0:
        record["rec_rel"] = float(r[-1]) / r0
        if res.true_residual is not None:
            record["true_rel"] = float(res.true_residual) / r0


def _run_contact(case: StressCase, spec: Any, record: dict[str, Any]) -> None:
    from threadpoolctl import threadpool_limits

    # one BLAS thread, as ddsolve.solve does (small blocks; see README "Performance notes")
    with threadpool_limits(limits=1, user_api="blas"):
        _solve_contact(case, spec, record)


def _solve_contact(case: StressCase, spec: Any, record: dict[str, Any]) -> None:
    from ..api import build_scene, check_decomposition
    from ..contact import ContactProblem, solve_contact_direct
    from ..contact.run import run_contact_method
    from ..dd import Substructures
    from ..scene import assemble
    from ..scene.contact import two_membranes

    check_decomposition(spec)
    if case.load is not None:
        loads = contact_load(case.load, spec.subdomains, spec.elements)
        scene = two_membranes(spec.subdomains, spec.elements, f=loads)
    else:
        scene = build_scene(spec)
    h = 1.0 / (spec.subdomains * spec.elements)
    on2 = scene.subdomain_body[scene.element_subdomain] == 1
    f_el = np.broadcast_to(np.asarray(scene.f, dtype=float), on2.shape)
    net = -float(f_el[on2].sum()) * h * h                   # load the contact pressure must carry
    problem = ContactProblem(Substructures(assemble(scene), scaling=spec.scaling, gamma=spec.gamma))
    ref = solve_contact_direct(problem)
    sol = ref if spec.method == "direct" else run_contact_method(spec.method, problem, rtol=float(spec.rtol),
                                                                 maxiter=int(spec.maxiter))
    kkt = problem.kkt(sol.u, sol.lam).max
    record["nonfinite"] = [k for k, v in {"u": sol.u, "lambda": sol.lam, "kkt": kkt}.items() if not _finite(v)]
    u_ref, lam_ref = ref.u, ref.lam
    record.update(
        converged=bool(sol.converged), reason=sol.reason, iterations=int(sol.total_iterations),
        error_vs_direct=float(np.linalg.norm(sol.u - u_ref) / max(np.linalg.norm(u_ref), 1e-300)),
        lambda_error=float(np.linalg.norm(sol.lam - lam_ref) / max(np.linalg.norm(lam_ref), 1e-300)),
        force_error=float(abs(sol.lam.sum() - net) / max(abs(net), 1e-300)), net_load=net,
        n_active=int(np.count_nonzero(sol.active)), n_active_direct=int(np.count_nonzero(ref.active)),
        n_contact=int(problem.n_contact), kkt=float(kkt), restarts=0)
    grad = np.asarray(sol.extra.get("gradient_norms", []), dtype=float)
    norm_b = float(sol.extra.get("norm_b", 0.0))
    if grad.size and norm_b > 0:
        record["smalbe_gradient"] = float(grad[-1]) / norm_b


# --------------------------------------------------------------------------- #
# Criteria
# --------------------------------------------------------------------------- #
Verdict = tuple[bool, str]


def _clean_run(rec: Mapping[str, Any]) -> Verdict | None:
    """FAIL for a crash, a timeout or a silent NaN (non-finite output of a 'converged' solve)."""
    if rec["status"] in ("crash", "timeout"):
        return False, f"{rec['status']}: {rec['error']}"
    if rec["status"] == "ok" and rec["nonfinite"] and rec["converged"]:
        return False, f"converged with non-finite {', '.join(rec['nonfinite'])}"
    if rec["status"] == "ok" and rec["nonfinite"] and not rec["reason"]:
        return False, f"non-finite {', '.join(rec['nonfinite'])} without a reason"
    return None


def _accuracy(rec: Mapping[str, Any]) -> Verdict:
    """Converged, true residual within TRUE_FACTOR of max(recursive, rtol), small error vs direct.

    The error bound is ERROR_FACTOR rtol, times sqrt(cond) where a condition estimate is
    known (the energy-norm error of a solve to a relative residual rtol grows like that).
    """
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    if not rec["converged"]:
        return False, f"not converged: {rec['reason']}"
    rtol = rec["rtol"]
    if rec["true_rel"] is not None and rec["rec_rel"] is not None:
        if rec["true_rel"] > TRUE_FACTOR * max(rec["rec_rel"], rtol):
            return False, f"true residual {rec['true_rel']:.1e} >> recursive {rec['rec_rel']:.1e}"
    err = rec["error_vs_direct"]
    bound = ERROR_FACTOR * rtol * math.sqrt(max(rec["cond"] or 1.0, 1.0))
    if err is None or err > bound:
        return False, f"error vs direct {err} > {bound:.1e}"
    return True, ""


def _ratio(rec: Mapping[str, Any], base: Mapping[str, Any] | None, key: str) -> float | None:
    if base is None or base.get(key) in (None, 0) or rec.get(key) is None:
        return None
    return float(rec[key]) / float(base[key])


def _crit_accurate(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    return _accuracy(rec)


def _crit_robust(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    ok, note = _accuracy(rec)
    ratio = _ratio(rec, base, "iterations")
    if ratio is None:
        return False, note or "no baseline iterations"
    note = (note + "; " if note else "") + f"{ratio:.2f}x iterations of rho = 1"
    return ok and ratio <= ROBUST_FACTOR, note


def _crit_not_robust(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    if not rec["converged"]:
        return bool(rec["reason"]), f"expected failure seen: no convergence ({rec['reason'][:60]})"
    it = _ratio(rec, base, "iterations")
    cond = _ratio(rec, base, "cond")
    seen = (it is not None and it > ROBUST_FACTOR) or (cond is not None and cond >= COND_GROWTH)
    parts = [f"{it:.2f}x iterations" if it is not None else "", f"{cond:.3g}x cond" if cond is not None else ""]
    note = ", ".join(p for p in parts if p) + " of rho = 1"
    return seen, ("expected non-robustness seen: " if seen else "no non-robustness seen: ") + note


def _crit_scalable(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    ok, note = _accuracy(rec)
    ratio = _ratio(rec, base, "iterations")
    if ratio is None:
        return False, note or "no baseline"
    note = (note + "; " if note else "") + f"{ratio:.2f}x iterations of the baseline"
    return ok and ratio <= ROBUST_FACTOR, note


def _crit_polylog(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    ok, note = _accuracy(rec)
    if base is None or base.get("cond") is None or rec.get("cond") is None:
        return False, note or "no condition estimates"
    m, m0 = rec["spec"]["elements"], base["spec"]["elements"]
    bound = ((1 + math.log(m)) / (1 + math.log(m0))) ** 2
    ratio = rec["cond"] / base["cond"]
    note = (note + "; " if note else "") + f"cond ratio {ratio:.2f} <= {bound:.2f}"
    return ok and ratio <= bound, note


def _rejected(rec: Mapping[str, Any]) -> Verdict | None:
    """PASS for an input error the case allows (``expect_message``), e.g. a load the scene rejects."""
    want = rec.get("expect_message")
    if rec["status"] == "input_error" and want and want in rec["error"] and "\n" not in rec["error"]:
        return True, f"rejected as input: {rec['error'][:90]}"
    return None


def _crit_contact_reference(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if _rejected(rec):
        return _rejected(rec)
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    notes = []
    if not rec["converged"]:
        notes.append(f"not converged: {rec['reason']}")
    if rec["kkt"] > REFERENCE_KKT:
        notes.append(f"KKT {rec['kkt']:.1e} > {REFERENCE_KKT:g}")
    if rec["force_error"] > REFERENCE_FORCE:
        notes.append(f"contact force off the net load by {rec['force_error']:.1e}")
    want = rec.get("expect_active")
    if want == "all" and rec["n_active"] != rec["n_contact"]:
        notes.append(f"{rec['n_active']} of {rec['n_contact']} pairs active, designed: all")
    if want == "1" and rec["n_active"] != 1:
        notes.append(f"{rec['n_active']} pairs active, designed: 1")
    zone = f"{rec['n_active']}/{rec['n_contact']} active, force error {rec['force_error']:.1e}"
    return not notes, "; ".join(notes) if notes else zone


def _crit_contact_agree(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if _rejected(rec):
        return _rejected(rec)
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    if not rec["converged"]:
        return bool(rec["reason"]), f"failed cleanly: {rec['reason'][:70]}"
    tol = ERROR_FACTOR * rec["rtol"]
    notes = []
    if rec["error_vs_direct"] > tol:
        notes.append(f"u error {rec['error_vs_direct']:.1e}")
    if rec["lambda_error"] > tol:
        notes.append(f"lambda error {rec['lambda_error']:.1e}")
    if rec["n_active"] != rec["n_active_direct"]:
        notes.append(f"{rec['n_active']} active vs {rec['n_active_direct']}")
    if notes:
        return False, "converged=True but disagrees with direct: " + ", ".join(notes) + f" (> {tol:.0e})"
    return True, (f"{rec['n_active']}/{rec['n_contact']} active, lambda error {rec['lambda_error']:.1e}, "
                  f"force error {rec['force_error']:.1e}")


def _crit_input_error(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if rec["status"] != "input_error":
        return False, f"expected an input error, got status {rec['status']} ({rec['reason'] or rec['error']})"
    msg = rec["error"]
    want = rec.get("expect_message") or ""
    ok = "\n" not in msg and want in msg
    return ok, msg if len(msg) <= 110 else msg[:107] + "..."


def _crit_not_converged(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    if rec["converged"]:
        return False, f"claims convergence: {rec['reason']}"
    return bool(rec["reason"]), rec["reason"][:110]


#: Criterion key -> (the rule in words, its check(record, baseline record) -> (passed, note)).
CRITERIA: dict[str, tuple[str, Callable[[Mapping[str, Any], Mapping[str, Any] | None], Verdict]]] = {
    "accurate": (f"converged; true residual <= {TRUE_FACTOR:g} max(recursive, rtol); "
                 f"error vs direct <= {ERROR_FACTOR:g} rtol max(1, sqrt(cond))", _crit_accurate),
    "robust": (f"accurate, and iterations <= {ROBUST_FACTOR:g}x those of rho = 1", _crit_robust),
    "not_robust": (f"clean run showing the predicted non-robustness: iterations > {ROBUST_FACTOR:g}x, "
                   f"or cond >= {COND_GROWTH:g}x, those of rho = 1, or no convergence (with a reason)",
                   _crit_not_robust),
    "scalable": (f"accurate, and iterations <= {ROBUST_FACTOR:g}x those of the baseline", _crit_scalable),
    "polylog": ("accurate, and cond / cond(baseline) <= ((1 + log H/h) / (1 + log H/h_baseline))^2",
                _crit_polylog),
    "contact_reference": (f"converged; KKT <= {REFERENCE_KKT:g}; sum(lambda) = net load to {REFERENCE_FORCE:g}; "
                          f"the designed contact zone (roundoff case: or the load is rejected as input)",
                          _crit_contact_reference),
    "contact_agree": (f"converged=False with a reason, or u and lambda within {ERROR_FACTOR:g} rtol of "
                      f"direct and the same active set (roundoff case: or the load is rejected as input)",
                      _crit_contact_agree),
    "input_error": ("InputError with a one-line message naming the field", _crit_input_error),
    "not_converged": ("no exception; converged=False with a reason; no silent NaN", _crit_not_converged),
}


def evaluate(records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Apply the criteria: each record gets ``outcome`` ("PASS"/"FAIL") and ``note``.

    Parameters
    ----------
    records : sequence of dict
        Records of :func:`run_case` (baselines among them).

    Returns
    -------
    list of dict
        The records in input order, with ``outcome`` and ``note`` added.
    """
    by_name = {rec["name"]: rec for rec in records}
    rows = []
    for rec in records:
        base = by_name.get(rec["baseline"]) if rec.get("baseline") else None
        verdict = _clean_run(rec)
        if verdict is None:
            if rec.get("baseline") and base is None:
                verdict = (False, f"baseline {rec['baseline']} missing")
            else:
                verdict = CRITERIA[rec["criterion"]][1](rec, base)
        passed, note = verdict
        if rec.get("restarts"):
            note = (note + "; " if note else "") + f"{rec['restarts']} PCR restart(s)"
        rows.append({**rec, "outcome": "PASS" if passed else "FAIL", "note": note})
    return rows


# --------------------------------------------------------------------------- #
# Report
# --------------------------------------------------------------------------- #
def _num(value: Any, fmt: str = ".1e") -> str:
    return "–" if value is None else format(value, fmt)


def _markdown_cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def render_markdown(rows: Sequence[Mapping[str, Any]], *, title: str = "Numerical stability stress tests") -> str:
    """The report: a summary, the criteria, then one table per group with one row per case.

    Parameters
    ----------
    rows : sequence of dict
        Output of :func:`evaluate`.
    title : str

    Returns
    -------
    str
        Markdown text.
    """
    n_fail = sum(r["outcome"] == "FAIL" for r in rows)
    lines = [f"# {title}", "",
             f"{len(rows)} cases: {len(rows) - n_fail} PASS, {n_fail} FAIL.", "",
             "Columns: *iter* = Krylov iterations (contact: all inner iterations); *cond* = Lanczos "
             "estimate (PCG methods only); *true* / *rec.* = residual recomputed from the final iterate / "
             "recursively updated residual, both relative to ||r_0|| (contact: *true* is the relative KKT "
             "residual (5.5) of (u, lambda), *rec.* SMALBE's final ||g^P|| / ||b||); *err* = relative "
             "energy-norm error against the direct solver (contact: relative l2 error of u); *outcome* "
             "against the row's criterion.", "", "Criteria:", ""]
    lines += [f"- `{key}`: {text}" for key, (text, _) in CRITERIA.items()]
    for group, heading in GROUPS.items():
        part = [r for r in rows if r["group"] == group]
        if not part:
            continue
        fails = sum(r["outcome"] == "FAIL" for r in part)
        lines += ["", f"## {heading}", "", f"{len(part)} cases, {fails} FAIL.", "",
                  "| case | what it proves | iter | cond | true | rec. | err | criterion | outcome | note |",
                  "|---|---|---:|---:|---:|---:|---:|---|---|---|"]
        for r in part:
            contact = r["spec"].get("problem") == "contact" and r["runner"] == "contact"
            true = r.get("kkt") if contact else r["true_rel"]
            rec = r.get("smalbe_gradient") if contact else r["rec_rel"]
            it = "–" if r["iterations"] is None else str(r["iterations"])
            if not r["converged"] and r["status"] == "ok":
                it += "*"
            cells = [f"`{r['name']}`", r["claim"], it, _num(r["cond"], ".3g"), _num(true), _num(rec),
                     _num(r["error_vs_direct"]), f"`{r['criterion']}`", f"**{r['outcome']}**", r["note"]]
            lines.append("| " + " | ".join(_markdown_cell(c) for c in cells) + " |")
    lines += ["", "`*`: not converged (the reason is in the note or in the case's record).", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------- #
# Files
# --------------------------------------------------------------------------- #
def write_records(path: str | os.PathLike, records: Sequence[Mapping[str, Any]]) -> Path:
    """Write records as one JSON list, atomically (temporary file, then rename)."""
    from ..io.hdf5 import atomic_target

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_target(path) as tmp:
        tmp.write_text(json.dumps(list(records), indent=1, allow_nan=False) + "\n")
    return path


def read_records(paths: Sequence[str | os.PathLike]) -> list[dict[str, Any]]:
    """Concatenate the record lists of several files, in order."""
    out: list[dict[str, Any]] = []
    for p in paths:
        out += json.loads(Path(p).read_text())
    return out
