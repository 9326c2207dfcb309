"""Plots of condition number estimates against H/h, with least-squares fits.

The theory for FETI, FETI-DP and BDDC (thesis, Chapter 2) bounds the condition
number by ``C (1 + log(H/h))^2`` (natural logarithm). :func:`~ddstudies.report.fits.fit_log_squared`
fits the constant C by least squares (a one-parameter fit, no intercept);
:func:`plot_cond_vs_Hh` draws one panel per method, one marker series per
number of subdomains per side 1/H (N_s), and the fitted curve a + C (1 + log(H/h))^2
(:func:`fit_log_squared_affine`) of each (method, N_s) series, because C depends on the
method and, before the asymptotic regime, on N_s. a, C and R^2 appear in the legend.

For the multibody study (thesis Section 4.4), :func:`plot_sweep_fits` draws
values against one varied parameter for several series (contact cases I and
II), ours as filled markers with a dashed fitted curve and the thesis's as open
markers with a dotted one, using one of the :data:`FIT_MODELS`: ``linear``
(a x + b), ``log_linear`` (a + b log x, see :func:`fit_log_linear`) or
``log_squared_affine`` (C1 + C2 (1 + log x)^2, see
:func:`fit_log_squared_affine`). :func:`multibody_sweep` and
:func:`thesis_sweep` pick such series from the runs and from a thesis
transcription; :func:`plot_multibody_sweep` does both.
:func:`plot_iterations_vs_HbHs` puts both methods' iterations against H_b/H_s
on one figure (per contact case) with the laws the theory suggests: FETI-FETI
a + b sqrt(H_b/H_s) (its condition number grows linearly in H_b/H_s, so CG needs
O(sqrt(cond)) steps) and the hybrid method a + b log(H_b/h) (the log(H_b/h)
factor of Theorem 4.3.6 with H_s/h fixed); :func:`hbhs_growth` gives the same
fits and the growth between two H_b/H_s values as a table.

Uses the non-interactive Agg backend.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Callable, Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ddsolve.io.hdf5 import atomic_target  # noqa: E402

from .fits import (_finite_pairs, _fit_linear_model, _fit_log_linear_model,  # noqa: E402,F401 (re-exported)
                   _fit_log_squared_affine_model, _fit_sqrt_linear_model, _r_squared, fit_linear,
                   fit_log_linear, fit_log_squared, fit_log_squared_affine, fit_sqrt_linear, log_squared,
                   r2_text)
from .rule_sets import DEFAULT, chosen_rule_set, one_rule_set, rule_sets  # noqa: E402
from .tables import (_truthy, CONTACT_CASES, LATEX_LABELS, METHOD_LABELS, MULTIBODY_ROW_LABELS,  # noqa: E402
                     ROW_LABELS, THESIS_KEYS, THESIS_QUANTITIES)


def _save(fig, path) -> Path | None:
    """Write ``fig`` to ``path`` (its format from the suffix, 120 dpi) atomically and close it; nothing when
    ``path`` is None (a review: figures were written straight to their final name)."""
    if path is None:
        return None
    path = Path(path)
    try:
        with atomic_target(path) as tmp:
            fig.savefig(tmp, dpi=120, format=path.suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return path

def label_narrow_log_axis(axis, low: float, high: float) -> None:
    """Label a log axis whose range ``low``..``high`` spans less than about two decades at round values
    (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 times a power of ten), where matplotlib labels one decade tick or
    none (a review: the data between 1.2 and 2.6 of a panel, the ratios below 2 of another, unlabelled)."""
    from matplotlib.ticker import LogLocator, NullFormatter, NullLocator, ScalarFormatter

    if not (0 < low < high < 100 * low):
        return
    subs = (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0) if high < 10 * low else (1.0, 2.0, 5.0)
    axis.set_major_locator(LogLocator(base=10, subs=subs))
    formatter = ScalarFormatter()
    formatter.set_scientific(False)
    axis.set_major_formatter(formatter)
    axis.set_minor_locator(NullLocator())
    axis.set_minor_formatter(NullFormatter())


#: Fit models of :func:`plot_sweep_fits`: name -> (fit(x, y) -> (params, r2),
#: curve(params, x) -> y, legend text of the params).
FIT_MODELS: dict[str, tuple[Callable, Callable, Callable]] = {
    "linear": (_fit_linear_model,
               lambda p, x: p[0] * np.asarray(x, dtype=float) + p[1],
               lambda p: f"{_fmt(p[0], '.3g')} x {_signed(p[1])}"),
    "log_linear": (_fit_log_linear_model,
                   lambda p, x: p[0] + p[1] * np.log(np.asarray(x, dtype=float)),
                   lambda p: f"{_fmt(p[0], '.3g')} {_signed(p[1])} log x"),
    "sqrt_linear": (_fit_sqrt_linear_model,
                    lambda p, x: p[0] + p[1] * np.sqrt(np.asarray(x, dtype=float)),
                    lambda p: f"{_fmt(p[0], '.3g')} {_signed(p[1])} √x"),
    "log_squared_affine": (_fit_log_squared_affine_model,
                           lambda p, x: p[0] + p[1] * log_squared(x),
                           lambda p: f"$C_1$={_fmt(p[0], '.3g')}, $C_2$={_fmt(p[1], '.3g')}"),
}
#: Formula of each model for the legend title.
FIT_FORMULAS: dict[str, str] = {
    "linear": "fit a x + b",
    "log_linear": "fit a + b log x",
    "sqrt_linear": "fit a + b √x",
    "log_squared_affine": "fit $C_1 + C_2 (1 + \\log x)^2$",
}


def plot_sweep_fits(series: Mapping[str, tuple], path: str | os.PathLike | None = None, *,
                    model: str, reference: Mapping[str, tuple] | None = None,
                    xlabel: str = "x", ylabel: str = "y", title: str | None = None,
                    logx: bool = False, reference_label: str = "thesis",
                    failed: Mapping[str, tuple] | None = None) -> dict:
    """Values against one parameter, several series, each with a least-squares fit.

    Parameters
    ----------
    series : mapping
        ``{label: (x, y)}``: our values, filled markers and a dashed fitted curve.
    path : path-like, optional
        Where to save the figure (PNG by extension); the figure is closed then.
    model : str
        A key of :data:`FIT_MODELS`.
    reference : mapping, optional
        ``{label: (x, y)}``: reference values (the thesis's), open markers and a
        dotted fitted curve in the colour of the series with the same label.
    xlabel, ylabel, title : str
        Axis labels and figure title.
    logx : bool
        Logarithmic x axis (base 2, ticks at the data).
    reference_label : str
        Name of the reference values in the legend.
    failed : mapping, optional
        ``{label: (x, y)}``: our runs that did not converge, crosses in the colour of the series,
        not fitted.

    Returns
    -------
    dict
        ``{(label, "ours" | reference_label): (params, r2)}``; params is
        (a, b) for ``linear`` (a x + b), (a, b) for ``log_linear`` (a + b log x)
        and (C1, C2) for ``log_squared_affine``; NaN where a fit is impossible.
    """
    if model not in FIT_MODELS:
        raise ValueError(f"unknown model {model!r} (choose from {', '.join(FIT_MODELS)})")
    fit, curve, describe = FIT_MODELS[model]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    markers = ["o", "s", "^", "D", "v", "P"]
    reference = dict(reference or {})
    failed = dict(failed or {})
    labels = list(dict.fromkeys([*series, *reference, *failed]))
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    fits: dict[tuple[str, str], tuple[tuple[float, ...], float]] = {}
    xticks: set[float] = set()
    for k, label in enumerate(labels):
        color, marker = colors[k % len(colors)], markers[k % len(markers)]
        if label in failed:
            _plot_not_converged(ax, failed[label], color, f"{label} ours", xticks)
        for who, data, filled, style in (("ours", series.get(label), True, "--"),
                                         (reference_label, reference.get(label), False, ":")):
            if data is None:
                continue
            x, y = _finite_pairs(*data)
            if x.size == 0:
                continue
            order = np.argsort(x)
            x, y = x[order], y[order]
            xticks.update(x.tolist())
            params, r2 = fit(x, y)
            fits[(label, who)] = (params, r2)
            text = f"{label} {who}: {describe(params)}, {_r2_text(r2, x.size)}"
            ax.plot(x, y, linestyle="none", marker=marker, color=color, label=text,
                    markerfacecolor=color if filled else "none", markersize=6 if filled else 8)
            if all(math.isfinite(v) for v in params) and x.max() > x.min():
                xs = np.geomspace(x.min(), x.max(), 200) if logx else np.linspace(x.min(), x.max(), 200)
                ax.plot(xs, curve(params, xs), linestyle=style, color=color, linewidth=1)
    if logx:
        ax.set_xscale("log", base=2)
    if xticks:
        ticks = sorted(xticks)
        ax.set_xticks(ticks)
        ax.set_xticklabels([_plain_number(t) for t in ticks])
        if logx:
            ax.minorticks_off()
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="major", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize="small", title=FIT_FORMULAS.get(model), title_fontsize="small")
    else:
        ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    _save(fig, path)
    return fits


def _sweep_rows(frame: pd.DataFrame, keys: Mapping[str, str], x: str, base: Sequence[int]) -> pd.DataFrame:
    """Rows of ``frame`` equal to ``base`` in every key but ``x`` (keys: ours -> frame's names)."""
    ours = list(THESIS_KEYS)
    if x not in ours:
        raise KeyError(f"x must be one of {', '.join(ours)}, got {x!r}")
    mask = np.ones(len(frame), dtype=bool)
    for key, value in zip(ours, base):
        if key != x:
            mask &= pd.to_numeric(frame[keys[key]], errors="coerce").to_numpy() == int(value)
    return frame[mask]


def multibody_sweep(df: pd.DataFrame, *, method: str, x: str, y: str, base: Sequence[int],
                    contacts: Sequence[str] = ("full", "middle")) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Our runs of ``method`` that vary only ``x`` from ``base``, one series per contact case.

    Parameters
    ----------
    df : DataFrame
        Aggregated runs (columns method, contact, bodies, subdomains, elements, ``y``).
    x : {"bodies", "subdomains", "elements"}
        The varied parameter.
    base : (bodies, subdomains, elements)
        The base case; the other two keys are fixed at its values.

    Returns
    -------
    dict
        ``{"(I)": (x values, y values), ...}`` sorted by x, for the contacts with runs.
    """
    out = {}
    rows = _sweep_rows(df[df["method"] == method], {k: k for k in THESIS_KEYS}, x, base)
    for contact in contacts:
        sub = rows[rows["contact"] == contact].sort_values(x)
        if not sub.empty:
            out[f"({CONTACT_CASES[contact]})"] = (pd.to_numeric(sub[x]).to_numpy(dtype=float),
                                                  pd.to_numeric(sub[y], errors="coerce").to_numpy(dtype=float))
    return out


def thesis_sweep(thesis: pd.DataFrame, *, x: str, y: str, base: Sequence[int],
                 contacts: Sequence[str] = ("full", "middle")) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Like :func:`multibody_sweep` for a thesis transcription (tables/table_4_*.csv)."""
    out = {}
    rows = _sweep_rows(thesis, THESIS_KEYS, x, base).sort_values(THESIS_KEYS[x])
    for contact in contacts:
        column = f"{THESIS_QUANTITIES.get(y, y)}_{CONTACT_CASES[contact]}"
        if column in rows.columns and not rows.empty:
            out[f"({CONTACT_CASES[contact]})"] = (pd.to_numeric(rows[THESIS_KEYS[x]]).to_numpy(dtype=float),
                                                  pd.to_numeric(rows[column], errors="coerce").to_numpy(dtype=float))
    return out


def plot_multibody_sweep(df: pd.DataFrame, thesis: pd.DataFrame | None, path: str | os.PathLike | None = None,
                         *, method: str, x: str, y: str, base: Sequence[int], model: str,
                         contacts: Sequence[str] = ("full", "middle"), logx: bool = False,
                         title: str | None = None, rule_set: str = DEFAULT) -> dict:
    """Figures 4.2 / 4.3 style: ``y`` of ``method`` against ``x`` from ``base``, cases I and II.

    Our values (:func:`multibody_sweep`, the runs of rule set ``rule_set`` only:
    :func:`~ddstudies.report.rule_sets.one_rule_set`) and the thesis's
    (:func:`thesis_sweep`, when ``thesis`` is given) with fits of ``model``; see
    :func:`plot_sweep_fits` for the returned fits.
    """
    rule_set = chosen_rule_set(df, rule_set)
    fixed_rules = f", rule set {rule_set}" if len(rule_sets(df)) > 1 or rule_set != DEFAULT else ""
    df = one_rule_set(df, rule_set)   # one run per case (a study may sweep `presets`)
    converged = _converged_mask(df)     # a run that did not converge is drawn, not fitted (a review)
    series = multibody_sweep(df[converged], method=method, x=x, y=y, base=base, contacts=contacts)
    failed = multibody_sweep(df[~converged], method=method, x=x, y=y, base=base, contacts=contacts)
    reference = thesis_sweep(thesis, x=x, y=y, base=base, contacts=contacts) if thesis is not None else None
    def math_label(key: str) -> str:
        label = MULTIBODY_ROW_LABELS.get(key, key)
        return LATEX_LABELS.get(label, label)

    fixed = ", ".join(f"{math_label(k)} = {int(v)}" for k, v in zip(THESIS_KEYS, base) if k != x) + fixed_rules
    ylabel = {"cond": "condition number estimate", "iterations": "iterations"}.get(y, y)
    full_title = f"{title}\n({fixed})" if title else f"{METHOD_LABELS.get(method, method)} ({fixed})"
    return plot_sweep_fits(series, path, model=model, reference=reference,
                           xlabel=math_label(x), ylabel=ylabel, title=full_title, logx=logx, failed=failed)


#: The laws of :func:`plot_iterations_vs_HbHs` / :func:`hbhs_growth`: (method, quantity) ->
#: (model, variable, legend text). The variable is H_b/H_s (``"x"``) or H_b/h = H_b/H_s * H_s/h
#: (``"Hb_over_h"``).
HBHS_LAWS: dict[tuple[str, str], tuple[str, str, str]] = {
    ("feti-feti", "cond"): ("linear", "x", "a + b·(H_b/H_s)"),
    ("feti-feti", "iterations"): ("sqrt_linear", "x", "a + b·√(H_b/H_s)"),
    ("hybrid", "iterations"): ("log_linear", "Hb_over_h", "a + b·log(H_b/h)"),
}


def _law_fit(model: str, variable: str, x, y, elements: int):
    """Fit one :data:`HBHS_LAWS` law: ``(a, b), r2`` of y ~ a + b g(v), v = x or x * elements."""
    v = np.asarray(x, dtype=float) * (elements if variable == "Hb_over_h" else 1)
    if model == "linear":
        (slope, intercept), r2 = _fit_linear_model(v, y)
        return (intercept, slope), r2
    return FIT_MODELS[model][0](v, y)


def _law_curve(model: str, variable: str, params, x, elements: int) -> np.ndarray:
    v = np.asarray(x, dtype=float) * (elements if variable == "Hb_over_h" else 1)
    g = {"linear": v, "sqrt_linear": np.sqrt(v), "log_linear": np.log(v)}[model]
    return params[0] + params[1] * g


def _crossing(feti: tuple, hybrid: tuple, elements: int, lo: float, hi: float = 1e6) -> float:
    """Smallest x in [lo, hi] where the fitted FETI-FETI iterations reach the hybrid's (NaN: none)."""
    xs = np.geomspace(lo, hi, 4001)
    diff = (_law_curve("sqrt_linear", "x", feti, xs, elements)
            - _law_curve("log_linear", "Hb_over_h", hybrid, xs, elements))
    above = np.flatnonzero(diff >= 0)
    if above.size == 0:
        return math.nan
    i = int(above[0])
    if i == 0:
        return float(xs[0])
    x0, x1, d0, d1 = xs[i - 1], xs[i], diff[i - 1], diff[i]
    return float(x0 + (x1 - x0) * (-d0) / (d1 - d0))


def hbhs_growth(df: pd.DataFrame, *, base: Sequence[int], contacts: Sequence[str] = ("full", "middle"),
                start: int = 4, end: int | None = None, rule_set: str = DEFAULT) -> pd.DataFrame:
    """Growth in H_b/H_s of FETI-FETI's cond and iterations and the hybrid's iterations.

    Only the runs of rule set ``rule_set`` (:func:`~ddstudies.report.rule_sets.one_rule_set`) that
    converged (a count capped at ``maxiter`` is not a growth).

    Parameters
    ----------
    df : DataFrame
        Aggregated runs (method, contact, bodies, subdomains, elements, cond, iterations).
    base : (bodies, subdomains, elements)
        The sweep varies H_b/H_s (``subdomains``) with 1/H_b and H_s/h fixed at ``base``.
    start, end : int
        The H_b/H_s values compared (default end: the largest run); a missing
        ``start`` falls back to the smallest run.

    Returns
    -------
    DataFrame
        One row per (contact case, method, quantity) of :data:`HBHS_LAWS` with runs:
        ``case``, ``method``, ``quantity``, ``from``, ``to`` (the H_b/H_s values),
        ``at_from``, ``at_to``, ``ratio`` = at_to / at_from, ``law`` (the fitted
        law), ``a``, ``b``, ``r2`` (least squares over the whole sweep) and
        ``crossing``: on the hybrid rows, the H_b/H_s where the fitted FETI-FETI
        iterations reach the fitted hybrid iterations (NaN if beyond 1e6 or
        no FETI-FETI runs).
    """
    df = one_rule_set(df, rule_set)   # one run per case (a study may sweep `presets`)
    df = df[_converged_mask(df)]      # a count capped at maxiter is no growth (a review: "17 -> 17" was fitted)
    elements = int(base[2])
    rows = []
    for contact in contacts:
        case = f"({CONTACT_CASES[contact]})"
        fitted = {}
        for (method, quantity), (model, variable, law) in HBHS_LAWS.items():
            series = multibody_sweep(df, method=method, x="subdomains", y=quantity, base=base,
                                     contacts=[contact]).get(case)
            if series is None:
                continue
            x, y = _finite_pairs(*series)
            if x.size == 0:
                continue
            lo = float(start) if start in x else float(x.min())
            hi = float(end) if end is not None and end in x else float(x.max())
            params, r2 = _law_fit(model, variable, x, y, elements)
            fitted[method, quantity] = params
            at_from, at_to = float(y[x == lo][0]), float(y[x == hi][0])
            rows.append({"case": case, "method": method, "quantity": quantity, "from": int(lo),
                         "to": int(hi), "at_from": at_from, "at_to": at_to,
                         "ratio": at_to / at_from if at_from else math.nan, "law": law,
                         "a": params[0], "b": params[1], "r2": r2, "points": int(x.size), "crossing": math.nan})
        pair = (fitted.get(("feti-feti", "iterations")), fitted.get(("hybrid", "iterations")))
        if all(p is not None and all(math.isfinite(v) for v in p) for p in pair):
            lo = min(r["from"] for r in rows if r["case"] == case)
            rows[-1]["crossing"] = _crossing(pair[0], pair[1], elements, lo)
    columns = ["case", "method", "quantity", "from", "to", "at_from", "at_to", "ratio", "law",
               "a", "b", "r2", "points", "crossing"]
    return pd.DataFrame(rows, columns=columns)


def plot_iterations_vs_HbHs(df: pd.DataFrame, theses: Mapping[str, pd.DataFrame | None] | None = None,
                            path: str | os.PathLike | None = None, *, base: Sequence[int],
                            contacts: Sequence[str] = ("full", "middle"), title: str | None = None,
                            rule_set: str = DEFAULT) -> dict:
    """FETI-FETI and hybrid iterations against H_b/H_s, one panel per contact case.

    Only the runs of rule set ``rule_set`` (:func:`~ddstudies.report.rule_sets.one_rule_set`).

    Our iterations are filled markers with the fitted law of :data:`HBHS_LAWS`
    (dashed; FETI-FETI a + b sqrt(H_b/H_s), hybrid a + b log(H_b/h) with
    H_b/h = H_b/H_s * H_s/h; runs that did not converge: crosses, not fitted); the thesis's (``theses = {"feti-feti": table 4.1,
    "hybrid": table 4.2}``) are open markers. A dotted vertical line marks the
    largest H_b/H_s of the thesis's tables: points to its right are ours only.

    Returns
    -------
    dict
        ``{(case, method): ((a, b), r2)}`` of our fits.
    """
    rule_set = chosen_rule_set(df, rule_set)
    fixed_rules = f", rule set {rule_set}" if len(rule_sets(df)) > 1 or rule_set != DEFAULT else ""
    df = one_rule_set(df, rule_set)   # one run per case (a study may sweep `presets`)
    converged = _converged_mask(df)
    theses = dict(theses or {})
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = {"feti-feti": (colors[0], "o"), "hybrid": (colors[1], "s")}
    elements = int(base[2])
    fig, axes = plt.subplots(1, max(len(contacts), 1), figsize=(6.0 * max(len(contacts), 1), 6.4),
                             sharey=True, squeeze=False)
    fits: dict[tuple[str, str], tuple[tuple[float, float], float]] = {}
    for ax, contact in zip(axes[0], contacts):
        case = f"({CONTACT_CASES[contact]})"
        xticks: set[float] = set()
        thesis_max = math.nan
        for method in ("feti-feti", "hybrid"):
            model, variable, law = HBHS_LAWS[(method, "iterations")]
            color, marker = styles[method]
            name = METHOD_LABELS.get(method, method)
            series = multibody_sweep(df[converged], method=method, x="subdomains", y="iterations", base=base,
                                     contacts=[contact]).get(case)
            failed = multibody_sweep(df[~converged], method=method, x="subdomains", y="iterations", base=base,
                                     contacts=[contact]).get(case)
            if failed is not None:      # drawn, not fitted (a review: counts capped at maxiter were fitted)
                _plot_not_converged(ax, failed, color, f"{name} ours", xticks)
            if series is not None:
                x, y = _finite_pairs(*series)
                if x.size:
                    xticks.update(x.tolist())
                    params, r2 = _law_fit(model, variable, x, y, elements)
                    fits[(case, method)] = (params, r2)
                    text = (f"{name} ours: {law}, a={_fmt(params[0], '.3g')}, b={_fmt(params[1], '.3g')}, "
                            f"{_r2_text(r2, x.size)}")
                    ax.plot(x, y, linestyle="none", marker=marker, color=color, label=text)
                    if all(math.isfinite(v) for v in params) and x.max() > x.min():
                        xs = np.linspace(x.min(), x.max(), 300)
                        ax.plot(xs, _law_curve(model, variable, params, xs, elements), linestyle="--",
                                color=color, linewidth=1)
            thesis = theses.get(method)
            if thesis is not None:
                ref = thesis_sweep(thesis, x="subdomains", y="iterations", base=base,
                                   contacts=[contact]).get(case)
                if ref is not None:
                    x, y = _finite_pairs(*ref)
                    if x.size:
                        xticks.update(x.tolist())
                        thesis_max = float(np.nanmax([thesis_max, x.max()]))
                        ax.plot(x, y, linestyle="none", marker=marker, color=color, markerfacecolor="none",
                                markersize=8, label=f"{name} thesis (Table {'4.1' if method == 'feti-feti' else '4.2'})")
        if math.isfinite(thesis_max) and xticks and max(xticks) > thesis_max:
            # in the legend, not as text on the axes: the text overlapped a marker (a review)
            ax.axvline(thesis_max, color="0.5", linestyle=":", linewidth=1,
                       label=f"end of the thesis's tables (H_b/H_s = {_plain_number(thesis_max)})")
        ticks = sorted(xticks)
        if ticks:
            ax.set_xticks(ticks)
            ax.set_xticklabels([_plain_number(t) for t in ticks], fontsize="small")   # every run labelled
        ax.set_title(f"case {case}: {'whole interface' if contact == 'full' else 'middle third'}")
        ax.set_xlabel("$H_b/H_s$")
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:     # below the panel: inside, it hid points (a review)
            ax.legend(fontsize="x-small", loc="upper center", bbox_to_anchor=(0.5, -0.14))
        else:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")
    axes[0][0].set_ylabel("iterations")
    fixed = f"$1/H_b$ = {int(base[0])}, $H_s/h$ = {elements}, $H_b/h = {elements}\\,H_b/H_s${fixed_rules}"
    fig.suptitle(f"{title}\n({fixed})" if title else f"Iterations against $H_b/H_s$ ({fixed})",
                 fontsize="medium")
    fig.tight_layout()
    _save(fig, path)
    return fits


def _fmt(value: float, spec: str) -> str:
    return "n/a" if not math.isfinite(value) else format(value, spec)


def _signed(value: float, spec: str = ".3g") -> str:
    """``+ 1.5`` or ``− 1.5`` (a term appended to a formula)."""
    if not math.isfinite(value):
        return "+ n/a"
    return f"{'−' if value < 0 else '+'} {format(abs(value), spec)}"


def plot_cond_vs_Hh(df: pd.DataFrame, path: str | os.PathLike | None = None, *,
                    methods: Sequence[str] | None = None, x: str = "elements",
                    group: str = "subdomains", y: str = "cond", title: str | None = None):
    """Condition number estimates against H/h with fitted ``a + C (1 + log(H/h))^2`` curves.

    Parameters
    ----------
    df : DataFrame
        Aggregated runs with columns ``method``, ``x``, ``group``, ``y``.
    path : path-like, optional
        Where to save the figure (PNG by extension); the figure is closed then.
    methods : sequence of str, optional
        Panels, in this order; default: order of appearance.
    x, group, y : str
        Columns for H/h (log axis), the series (N_s = 1/H) and the plotted value.
    title : str, optional
        Figure title.

    Returns
    -------
    dict
        ``{(method, group_value): (C, r2)}``: the fitted slope C of
        :func:`fit_log_squared_affine` and its R^2 (the intercept a is in the legend).
    """
    data = df.copy()
    for col in (x, group, y):
        data[col] = pd.to_numeric(data[col], errors="coerce")
    data = data[np.isfinite(data[y]) & np.isfinite(data[x]) & (data[x] > 0)]
    if methods is None:
        methods = list(dict.fromkeys(df["method"]))
    methods = list(methods) or ["(none)"]
    groups = sorted(data[group].dropna().unique())
    markers = ["o", "s", "^", "D", "v", "P", "X", "*", "<", ">"]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]

    fig, axes = plt.subplots(1, len(methods), figsize=(4.2 * len(methods) + 1.0, 4.2),
                             sharey=True, squeeze=False)
    fits: dict[tuple[str, float], tuple[float, float]] = {}
    glabel = ROW_LABELS.get(group, group)
    xlabel = ROW_LABELS.get(x, x)
    for ax, method in zip(axes[0], methods):
        sub = data[data["method"] == method]
        for k, gval in enumerate(groups):
            pts = sub[sub[group] == gval].sort_values(x)
            if pts.empty:
                continue
            color = colors[k % len(colors)]
            marker = markers[k % len(markers)]
            # a run that did not converge is drawn open and left out of the fit (a review: a run stopped at
            # maxiter was fitted as data); a table without the column counts every run as converged
            ok = _converged_mask(pts)
            good = pts[ok]
            # with an intercept: the bound's C (1 + log)^2 through the origin missed the points, R^2 < 0
            # at small H/h (a review); the constants of the estimate are not the bound's
            a, c, r2 = fit_log_squared_affine(good[x], good[y]) if len(good) else (math.nan,) * 3
            gname = int(gval) if float(gval).is_integer() else gval
            fits[(method, gname)] = (c, r2)
            label = (f"{glabel}={gname}: a={_fmt(a, '.3g')}, C={_fmt(c, '.3g')}, {_r2_text(r2, len(good))}"
                     if len(good) >= 2 else f"{glabel}={gname}: {_r2_text(r2, len(good))}")
            ax.plot(good[x], good[y], linestyle="none", marker=marker, color=color, label=label)
            if (~ok).any():
                ax.plot(pts[x][~ok], pts[y][~ok], linestyle="none", marker=marker, color=color,
                        markerfacecolor="none", label=f"{glabel}={gname}: not converged (not fitted)")
            if math.isfinite(c):
                xs = np.geomspace(good[x].min(), good[x].max(), 100) if good[x].max() > good[x].min() \
                    else np.array([good[x].min()])
                ax.plot(xs, a + c * log_squared(xs), linestyle="--", color=color, linewidth=1)
        ax.set_xscale("log", base=2)
        xticks = sorted(sub[x].unique())
        if xticks:
            ax.set_xticks(xticks)
            ax.set_xticklabels([_plain_number(t) for t in xticks])
        ax.set_title(METHOD_LABELS.get(method, method))
        ax.set_xlabel(xlabel)
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="small", title="fit a + C (1 + log(H/h))$^2$", title_fontsize="small")
        else:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")
    axes[0][0].set_ylabel("condition number estimate" if y == "cond" else y)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)
    return fits


def _r2_text(r2: float, n_points: int) -> str:
    """The legend's R^2 of a two-parameter fit (:func:`~ddstudies.report.fits.r2_text`): with two points it is
    1 by construction, so it is not shown as a measure of fit (a review: two-point fits read R^2 = 1.000)."""
    return r2_text(r2, n_points, label="$R^2$=")


def _plot_not_converged(ax, data: tuple, color: str, who: str, xticks: set) -> None:
    """Our runs that did not converge, ``data = (x, y)``: crosses in the series' colour, not fitted."""
    x, y = _finite_pairs(*data)
    if x.size:
        xticks.update(x.tolist())
        ax.plot(x, y, linestyle="none", marker="x", color=color, markersize=8,
                label=f"{who}: not converged (iteration limit or breakdown; not fitted)")


def _converged_mask(rows: pd.DataFrame) -> np.ndarray:
    """Whether each row's run converged (its ``converged`` column, read as a bool also from CSV text);
    all True without the column."""
    if "converged" not in rows.columns:
        return np.ones(len(rows), dtype=bool)
    return rows["converged"].map(_truthy).to_numpy(dtype=bool)      # as the tables read it


def _plain_number(value: float) -> str:
    value = float(value)
    return str(int(value)) if value.is_integer() else f"{value:g}"
