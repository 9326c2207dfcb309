"""Condition numbers of FETI-DP and BDDC on METIS partitions, with fitted laws (issue 11, item 3).

Two sweeps of the Poisson problem on netgen P1 meshes of the unit square
(:func:`ddsolve.scene.unstructured_scene`, ``parts`` METIS subdomains), each
case one :func:`ddsolve.solve` of a :class:`~ddsolve.spec.ProblemSpec` with
``mesh="unstructured"`` and ``cond=True`` (Lanczos estimate of the
preconditioned operator's condition number from the PCG coefficients):

* ``fixed_Hh``: H/h about constant, the number of subdomains P growing
  (``refine`` r and ``parts`` P grow together, P ~ 4^r, so that the dofs per
  subdomain stay about the same). Theory (Lee 2009, Sections 2.6 and 2.7: the
  FETI-DP and BDDC bound kappa <= C (1 + log(H/h))^2, C independent of H and h,
  hence of P at fixed H/h): cond and iterations level off. Fitted: cond = a + b log P (least squares), with
  max/min of cond over the sweep, and cond = c_inf - d / sqrt(P): the share
  of subdomains that touch the Dirichlet boundary (and so are not floating)
  falls like 1 / sqrt(P) for a square split into P compact parts, and c_inf is
  the value cond levels off at.
* ``fixed_P``: P fixed, the mesh refined (H/h growing). Fitted:
  cond = C (1 + log(H/h))^2 (least squares for C), cond = a + C (1 + log(H/h))^2,
  and the free exponent p of cond = c (1 + log(H/h))^p (a line in log-log).

H/h is measured as sqrt(ndof / P): the square root of the dofs per subdomain
(a subdomain of diameter H holds about (H/h)^2 nodes of a mesh of size h).
METIS partitions a refined mesh anew, so every point of ``fixed_P`` has its own
subdomain shapes: the condition numbers scatter around the law.
"""
from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from ..report.fits import r2_text
from ..report.plots import _save

#: The two sweeps of a ``cond_law`` config, in report order.
SWEEPS: tuple[str, ...] = ("fixed_Hh", "fixed_P")
#: What each sweep varies (report headings).
SWEEP_TITLES: dict[str, str] = {"fixed_Hh": "H/h about fixed, P growing",
                                "fixed_P": "P fixed, H/h growing (refinement)"}


@dataclass(frozen=True)
class CondCase:
    """One solve of the condition-number sweeps: a mesh (maxh, refine), its parts, a method and a primal set."""

    maxh: float
    refine: int
    parts: int
    method: str
    primal: str = "vertices"

    @property
    def stem(self) -> str:
        """File name without suffix: ``h<maxh>_r<refine>_P<parts>``, ``_<primal>`` unless vertices."""
        tag = "" if self.primal == "vertices" else "_" + self.primal.replace("+", "-")
        return f"h{self.maxh:g}_r{self.refine}_P{self.parts}{tag}"


def sweep_points(sweep: Mapping[str, Any]) -> list[tuple[float, int, int]]:
    """(maxh, refine, parts) of one sweep: ``parts`` one number or a list aligned with ``refine``."""
    refine = [int(r) for r in sweep["refine"]]
    parts = sweep["parts"]
    parts = [int(parts)] * len(refine) if isinstance(parts, (int, np.integer)) else [int(p) for p in parts]
    if len(parts) != len(refine):
        raise ValueError(f"parts: {len(parts)} values for {len(refine)} refinements")
    return [(float(sweep["maxh"]), r, p) for r, p in zip(refine, parts)]


def cond_cases(cond_law: Mapping[str, Any]) -> list[CondCase]:
    """Every case of a ``cond_law`` config (both sweeps x methods x primals), no duplicates, in order."""
    out: dict[CondCase, None] = {}
    for name in SWEEPS:
        if name not in cond_law:
            continue
        for maxh, refine, parts in sweep_points(cond_law[name]):
            for primal in cond_law.get("primals", ["vertices"]):
                for method in cond_law["methods"]:
                    out[CondCase(maxh, refine, parts, str(method), str(primal))] = None
    return list(out)


def case_spec(case: CondCase, *, rtol: float = 1e-8, maxiter: int = 1000) -> dict[str, Any]:
    """The :class:`~ddsolve.spec.ProblemSpec` mapping of one case (Poisson, unstructured, cond=True)."""
    spec = {"problem": "poisson", "mesh": "unstructured", "maxh": case.maxh, "refine": case.refine,
            "parts": case.parts, "method": case.method, "cond": True, "rtol": float(rtol), "maxiter": int(maxiter)}
    if case.primal != "vertices":   # the default's params as without the key (no rerun)
        spec["primal"] = case.primal
    return spec


# --------------------------------------------------------------------------- fits
@dataclass(frozen=True)
class LineFit:
    """y = a + b x by least squares, with R^2 and the number of points."""

    a: float
    b: float
    r2: float
    n_points: int


def _r2(y: np.ndarray, pred: np.ndarray) -> float:
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum((y - pred) ** 2)) / ss_tot if ss_tot > 0 else math.nan


def _r2_cell(fit: LineFit) -> str:
    """R^2 of a line fit for a table: with two points the line is exact and R^2 = 1 says nothing (a review:
    two-point fits read R^2 1.00 in the table, while the figures said "exact")."""
    return r2_text(fit.r2, fit.n_points, spec=".2f")


def fit_line(x: Iterable[float], y: Iterable[float]) -> LineFit:
    """Least-squares y = a + b x (at least 2 distinct x)."""
    x, y = np.asarray(list(x), dtype=float), np.asarray(list(y), dtype=float)
    if x.size < 2 or np.ptp(x) == 0:
        raise ValueError("a line fit needs at least 2 distinct abscissae")
    b, a = np.polyfit(x, y, 1)
    return LineFit(float(a), float(b), _r2(y, a + b * x), int(x.size))


@dataclass(frozen=True)
class PartsFit:
    """Sweep ``fixed_Hh``: cond and iterations against P."""

    cond: LineFit            # cond = a + b log P
    limit: LineFit           # cond = c_inf - d / sqrt(P): a = c_inf, b = -d
    iterations: LineFit      # iterations = a + b log P
    cond_ratio: float        # max cond / min cond over the sweep
    iterations_ratio: float  # max / min iterations
    last_step: float         # cond at the largest P over cond at the next smaller P of the sweep
    parts: tuple[int, int]   # smallest and largest P
    h_ratio: tuple[float, float]   # smallest and largest H/h of the sweep


def fit_parts(rows: pd.DataFrame) -> PartsFit:
    """cond = a + b log P, cond = c_inf - d / sqrt(P) and iterations = a + b log P on the rows of one method.

    ``rows`` has the columns parts, cond, iterations and H_over_h.
    """
    rows = rows.sort_values("parts")
    logp = np.log(rows["parts"].astype(float))
    cond, its = rows["cond"].astype(float), rows["iterations"].astype(float)
    return PartsFit(cond=fit_line(logp, cond), limit=fit_line(1.0 / np.sqrt(rows["parts"].astype(float)), cond),
                    iterations=fit_line(logp, its),
                    cond_ratio=float(cond.max() / cond.min()), iterations_ratio=float(its.max() / its.min()),
                    last_step=float(cond.iloc[-1] / cond.iloc[-2]),
                    parts=(int(rows["parts"].min()), int(rows["parts"].max())),
                    h_ratio=(float(rows["H_over_h"].min()), float(rows["H_over_h"].max())))


@dataclass(frozen=True)
class LogLawFit:
    """Sweep ``fixed_P``: cond against x = 1 + log(H/h)."""

    C: float                 # cond = C x^2 (least squares through the origin in x^2)
    r2: float
    offset: LineFit          # cond = a + C x^2 (a = offset.a, C = offset.b)
    exponent: float          # cond = c x^p: p (a line of log cond against log x)
    exponent_c: float
    exponent_r2: float
    n_points: int


def fit_log_law(h_ratio: Iterable[float], cond: Iterable[float]) -> LogLawFit:
    """The (1 + log(H/h))^2 law: C of cond = C x^2, a and C of cond = a + C x^2, and p of cond = c x^p.

    Parameters
    ----------
    h_ratio, cond : iterables of float, same length (at least 2 distinct H/h > 1/e)
        H/h of each point and its condition number.
    """
    x = 1.0 + np.log(np.asarray(list(h_ratio), dtype=float))
    y = np.asarray(list(cond), dtype=float)
    if x.size < 2 or np.ptp(x) == 0 or np.any(x <= 0):
        raise ValueError("the log law needs at least 2 distinct H/h > 1/e")
    x2 = x ** 2
    C = float(np.dot(x2, y) / np.dot(x2, x2))
    offset = fit_line(x2, y)
    p = fit_line(np.log(x), np.log(y))
    return LogLawFit(C=C, r2=_r2(y, C * x2), offset=offset, exponent=p.b, exponent_c=float(math.exp(p.a)),
                     exponent_r2=p.r2, n_points=int(x.size))


# --------------------------------------------------------------------------- table and summary
def cond_table(df: pd.DataFrame, cond_law: Mapping[str, Any]) -> pd.DataFrame:
    """One row per (sweep, method, primal, point): the collected results of the cases of each sweep.

    Parameters
    ----------
    df : DataFrame
        :func:`ddstudies.aggregate.collect` of the case files (columns maxh,
        refine, parts or param_parts, method, primal, ndof, cond, iterations, converged).
    cond_law : mapping
        The ``cond_law`` config (its sweeps name the points).

    Returns
    -------
    DataFrame
        Columns sweep, method, primal, maxh, refine, parts, ndof, H_over_h
        (sqrt(ndof / parts)), one_plus_log (1 + log(H/h)), cond, iterations, converged.
    """
    df = df.copy()
    if "parts" not in df or df["parts"].isna().all():
        df["parts"] = df["param_parts"]
    if "primal" not in df:
        df["primal"] = "vertices"
    rows = []
    for name in SWEEPS:
        if name not in cond_law:
            continue
        for maxh, refine, parts in sweep_points(cond_law[name]):
            hit = df[np.isclose(df["maxh"].astype(float), maxh) & (df["refine"].astype(int) == refine)
                     & (df["parts"].astype(int) == parts)]
            for _, row in hit.iterrows():
                rows.append({"sweep": name, "method": row["method"], "primal": row["primal"], "maxh": maxh,
                             "refine": refine, "parts": parts, "ndof": int(row["ndof"]),
                             "cond": float(row["cond"]), "iterations": int(row["iterations"]),
                             "converged": bool(row["converged"])})
    out = pd.DataFrame(rows, columns=["sweep", "method", "primal", "maxh", "refine", "parts", "ndof", "cond",
                                      "iterations", "converged"])
    out.insert(7, "H_over_h", np.sqrt(out["ndof"].astype(float) / out["parts"].astype(float)))
    out.insert(8, "one_plus_log", 1.0 + np.log(out["H_over_h"].astype(float)))
    return out.reset_index(drop=True)


def cond_law_summary(df: pd.DataFrame, cond_law: Mapping[str, Any]) -> dict[str, Any]:
    """The table and the fits of each (method, primal): ``parts_fits`` (fixed_Hh), ``log_fits`` (fixed_P)."""
    table = cond_table(df, cond_law)
    parts_fits, log_fits = {}, {}
    ok = table[table["converged"]]
    for (sweep, method, primal), rows in ok.groupby(["sweep", "method", "primal"], sort=False):
        try:
            if sweep == "fixed_Hh":
                parts_fits[(method, primal)] = fit_parts(rows.sort_values("parts"))
            else:
                log_fits[(method, primal)] = fit_log_law(rows["H_over_h"], rows["cond"])
        except ValueError:
            continue
    return {"table": table, "parts_fits": parts_fits, "log_fits": log_fits}


def cond_law_markdown(summary: Mapping[str, Any]) -> str:
    """The table and the fitted laws as markdown."""
    table: pd.DataFrame = summary["table"]
    lines = ["# Condition numbers on METIS partitions (Poisson, netgen P1)", "",
             "cond: Lanczos estimate of the preconditioned operator (PCG, rtol of the config); "
             "H/h = sqrt(ndof / P), the square root of the dofs per subdomain. `*`: not converged.", ""]
    shown = table.copy()
    shown["H_over_h"] = shown["H_over_h"].map(lambda v: f"{v:.1f}")
    shown["one_plus_log"] = shown["one_plus_log"].map(lambda v: f"{v:.2f}")
    shown["cond"] = [f"{c:.3f}" + ("" if ok else "*") for c, ok in zip(table["cond"], table["converged"])]
    lines.append(shown.drop(columns=["converged"]).to_markdown(index=False))
    if summary["parts_fits"]:
        lines += ["", f"## {SWEEP_TITLES['fixed_Hh']}: cond = a + b log P", "",
                  "| method | primal | P | H/h | a | b | R^2 | cond max/min | cond last step | "
                  "c_inf - d / sqrt(P) | R^2 | iterations a + b log P | iterations max/min |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for (method, primal), fit in summary["parts_fits"].items():
            lines.append(f"| {method} | {primal} | {fit.parts[0]}..{fit.parts[1]} | "
                         f"{fit.h_ratio[0]:.1f}..{fit.h_ratio[1]:.1f} | {fit.cond.a:.3f} | {fit.cond.b:.3f} | "
                         f"{_r2_cell(fit.cond)} | {fit.cond_ratio:.2f} | {fit.last_step:.2f} | "
                         f"{fit.limit.a:.3f} - {-fit.limit.b:.3f} / sqrt(P) | {_r2_cell(fit.limit)} | "
                         f"{fit.iterations.a:.1f} + "
                         f"{fit.iterations.b:.2f} log P | {fit.iterations_ratio:.2f} |")
        lines += ["", "cond last step: cond at the largest P over cond at the next smaller P of the sweep; 1 "
                  "where cond has levelled off. With few subdomains none or few are floating (all touch the "
                  "Dirichlet boundary), which keeps the first points low; their share falls like 1 / sqrt(P), "
                  "and c_inf of the fit c_inf - d / sqrt(P) is the value cond levels off at."]
    if summary["log_fits"]:
        lines += ["", f"## {SWEEP_TITLES['fixed_P']}: cond against x = 1 + log(H/h)", "",
                  "| method | primal | C of C x^2 | R^2 | a + C x^2 | R^2 | p of c x^p | R^2 | points |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for (method, primal), fit in summary["log_fits"].items():
            n = fit.n_points                  # two points fit the two-parameter laws exactly: no R^2
            lines.append(f"| {method} | {primal} | {fit.C:.4f} | {r2_text(fit.r2, n, n_params=1, spec='.2f')} | "
                         f"{fit.offset.a:.3f} + {fit.offset.b:.4f} x^2 | {r2_text(fit.offset.r2, n, spec='.2f')} | "
                         f"{fit.exponent:.2f} | {r2_text(fit.exponent_r2, n, spec='.2f')} | {n} |")
        lines += ["", "The bound kappa <= C (1 + log(H/h))^2 is an upper bound; where the free exponent p is "
                  "below 2 the measured range is pre-asymptotic (cond starts near 1 + a constant), which the "
                  "fit with an offset a shows."]
    return "\n".join(lines) + "\n"


_COLORS = {"fetidp": "tab:blue", "bddc": "tab:orange"}


def plot_cond_law(summary: Mapping[str, Any], path: str | os.PathLike | None):
    """Two panels: cond (and iterations) against P at fixed H/h; cond against 1 + log(H/h) at fixed P (log-log)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table: pd.DataFrame = summary["table"]
    fig, (ax_p, ax_h) = plt.subplots(1, 2, figsize=(14, 7.4))
    markers = {"vertices": "o", "vertices+edges": "s"}
    for (method, primal), rows in table[table["sweep"] == "fixed_Hh"].groupby(["method", "primal"], sort=False):
        rows = rows.sort_values("parts")
        color, marker = _COLORS.get(method, "tab:gray"), markers.get(primal, "^")
        fit = summary["parts_fits"].get((method, primal))
        ax_p.plot(rows["parts"], rows["cond"], marker=marker, linestyle="", color=color,
                  label=f"{method} ({primal})")
        if fit:
            p = np.geomspace(rows["parts"].min(), rows["parts"].max(), 50)
            ax_p.plot(p, fit.cond.a + fit.cond.b * np.log(p), "--", color=color,
                      label=f"{method} ({primal}): {fit.cond.a:.2f} + {fit.cond.b:.3f} log P")
            ax_p.plot(p, fit.limit.a + fit.limit.b / np.sqrt(p), "-", color=color, alpha=0.6,
                      label=f"{method} ({primal}): {fit.limit.a:.2f} - {-fit.limit.b:.2f} / sqrt(P) "
                            f"({r2_text(fit.limit.r2, fit.limit.n_points, spec='.2f', label='R^2 ')})")
            ax_p.axhline(fit.limit.a, color=color, lw=0.6, alpha=0.4, label=f"{method} ({primal}): its limit c_inf")
        ax_p.plot(rows["parts"], rows["iterations"] / 10.0, marker=marker, linestyle=":", color=color,
                  alpha=0.5, label=f"{method} ({primal}) iterations / 10")
    ax_p.set_xscale("log", base=2)
    ax_p.set_ylim(bottom=0)
    ax_p.set_xlabel("subdomains P (METIS)")
    ax_p.set_ylabel("condition number")
    ax_p.set_title(SWEEP_TITLES["fixed_Hh"])
    ax_p.grid(True, which="both", alpha=0.3)
    # the legends below the panels: inside they covered points (a review)
    ax_p.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2)
    for (method, primal), rows in table[table["sweep"] == "fixed_P"].groupby(["method", "primal"], sort=False):
        rows = rows.sort_values("H_over_h")
        color, marker = _COLORS.get(method, "tab:gray"), markers.get(primal, "^")
        fit = summary["log_fits"].get((method, primal))
        ax_h.plot(rows["one_plus_log"], rows["cond"], marker=marker, linestyle="", color=color,
                  label=f"{method} ({primal}), P = {int(rows['parts'].iloc[0])}")
        if fit:
            x = np.linspace(rows["one_plus_log"].min(), rows["one_plus_log"].max(), 50)
            poor = not fit.r2 > 0          # a bound C x^2 that the points do not follow: drawn faintly
            name = f"{method} ({primal})"       # every entry says whose fit it is (a review)
            ax_h.plot(x, fit.C * x ** 2, "--", color=color, alpha=0.3 if poor else 1.0, lw=0.8 if poor else 1.5,
                      label=f"{name}: {fit.C:.3f} x^2 "
                            f"({r2_text(fit.r2, fit.n_points, n_params=1, spec='.2f', label='R^2 ')})")
            ax_h.plot(x, fit.offset.a + fit.offset.b * x ** 2, "-", color=color, alpha=0.6,
                      label=f"{name}: {fit.offset.a:.2f} + {fit.offset.b:.3f} x^2 "
                            f"({r2_text(fit.offset.r2, fit.n_points, spec='.2f', label='R^2 ')})")
            ax_h.plot(x, fit.exponent_c * x ** fit.exponent, ":", color=color,
                      label=f"{name}: {fit.exponent_c:.2f} x^{fit.exponent:.2f} (free exponent)")
    from matplotlib.ticker import ScalarFormatter

    from ..report.plots import label_narrow_log_axis

    ax_h.set_xscale("log")
    ax_h.set_yscale("log")
    for axis in (ax_h.xaxis, ax_h.yaxis):
        axis.set_major_formatter(ScalarFormatter())
    label_narrow_log_axis(ax_h.xaxis, *ax_h.get_xlim())
    label_narrow_log_axis(ax_h.yaxis, *ax_h.get_ylim())
    ax_h.set_xlabel("x = 1 + log(H/h),  H/h = sqrt(dofs / P)")
    ax_h.set_ylabel("condition number")
    ax_h.set_title(SWEEP_TITLES["fixed_P"])
    ax_h.grid(True, which="major", alpha=0.3)
    ax_h.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2)
    fig.tight_layout()
    _save(fig, path)
    return fig


def require_points(cond_law: Mapping[str, Any]) -> None:
    """Each sweep needs 2 distinct points for its fit (else ValueError naming the sweep)."""
    for name in SWEEPS:
        if name in cond_law:
            points = sweep_points(cond_law[name])
            key = [p for _, _, p in points] if name == "fixed_Hh" else [r for _, r, _ in points]
            if len(set(key)) < 2:
                raise ValueError(f"{name}: needs at least 2 distinct {'parts' if name == 'fixed_Hh' else 'refine'}"
                                 f" values for its fit")


__all__: Sequence[str] = ["SWEEPS", "CondCase", "case_spec", "cond_cases", "cond_law_markdown", "cond_law_summary",
                          "cond_table", "fit_line", "fit_log_law", "fit_parts", "plot_cond_law", "require_points",
                          "sweep_points"]
