"""Plots of condition number estimates against H/h, with least-squares fits.

The theory for FETI, FETI-DP and BDDC (thesis, Chapter 2) bounds the condition
number by ``C (1 + log(H/h))^2`` (natural logarithm). :func:`fit_log_squared`
fits the constant C by least squares (a one-parameter fit, no intercept);
:func:`plot_cond_vs_Hh` draws one panel per method, one marker series per
number of subdomains per side 1/H (N_s), and the fitted curve of each
(method, N_s) series, because C depends on the method and, before the
asymptotic regime, on N_s. The fitted C and R^2 appear in the legend.

Uses the non-interactive Agg backend.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from .tables import METHOD_LABELS, ROW_LABELS  # noqa: E402


def _finite_pairs(x, y) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if x.shape != y.shape:
        raise ValueError(f"x and y differ in length: {x.size} != {y.size}")
    keep = np.isfinite(x) & np.isfinite(y)
    return x[keep], y[keep]


def _r_squared(y: np.ndarray, fitted: np.ndarray) -> float:
    """Coefficient of determination 1 - SS_res / SS_tot (SS_tot about the mean).

    NaN with fewer than two points or when all y are equal (SS_tot = 0). For a
    fit without intercept it can be negative (worse than the mean).
    """
    if y.size < 2:
        return math.nan
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    if ss_tot == 0.0:
        return math.nan
    ss_res = float(np.sum((y - fitted) ** 2))
    return 1.0 - ss_res / ss_tot


def log_squared(h_ratio) -> np.ndarray:
    """The model shape ``(1 + log(H/h))^2`` (natural logarithm)."""
    return (1.0 + np.log(np.asarray(h_ratio, dtype=float))) ** 2


def fit_log_squared(h_ratio, cond) -> tuple[float, float]:
    """Least-squares fit of ``cond ~ C (1 + log(H/h))^2``.

    Parameters
    ----------
    h_ratio : array_like
        H/h values (> 0).
    cond : array_like
        Condition number estimates. Pairs with a non-finite value are ignored.

    Returns
    -------
    (C, r2) : tuple of float
        ``C = sum(g * cond) / sum(g * g)`` with ``g = (1 + log(H/h))^2``, and
        R^2 (see :func:`_r_squared`; NaN for fewer than two points). C is NaN
        when no usable point is left.
    """
    x, y = _finite_pairs(h_ratio, cond)
    if np.any(x <= 0):
        raise ValueError("H/h must be positive")
    if x.size == 0:
        return math.nan, math.nan
    g = log_squared(x)
    denom = float(np.dot(g, g))
    if denom == 0.0:
        return math.nan, math.nan
    c = float(np.dot(g, y)) / denom
    return c, _r_squared(y, c * g)


def fit_linear(x, y) -> tuple[float, float, float]:
    """Least-squares line ``y ~ slope * x + intercept``.

    Returns
    -------
    (slope, intercept, r2) : tuple of float
        NaN slope/intercept with fewer than two distinct x values; R^2 as in
        :func:`fit_log_squared`.
    """
    x, y = _finite_pairs(x, y)
    if x.size < 2 or np.all(x == x[0]):
        return math.nan, math.nan, math.nan
    xm, ym = x.mean(), y.mean()
    slope = float(np.dot(x - xm, y - ym) / np.dot(x - xm, x - xm))
    intercept = float(ym - slope * xm)
    return slope, intercept, _r_squared(y, slope * x + intercept)


def _fmt(value: float, spec: str) -> str:
    return "n/a" if not math.isfinite(value) else format(value, spec)


def plot_cond_vs_Hh(df: pd.DataFrame, path: str | os.PathLike | None = None, *,
                    methods: Sequence[str] | None = None, x: str = "elements",
                    group: str = "subdomains", y: str = "cond", title: str | None = None):
    """Condition number estimates against H/h with fitted ``C (1 + log(H/h))^2`` curves.

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
        ``{(method, group_value): (C, r2)}``: the fitted constants.
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
            c, r2 = fit_log_squared(pts[x], pts[y])
            gname = int(gval) if float(gval).is_integer() else gval
            fits[(method, gname)] = (c, r2)
            label = f"{glabel}={gname}: C={_fmt(c, '.3g')}, $R^2$={_fmt(r2, '.3f')}"
            ax.plot(pts[x], pts[y], linestyle="none", marker=marker, color=color, label=label)
            if math.isfinite(c):
                xs = np.geomspace(pts[x].min(), pts[x].max(), 100) if pts[x].max() > pts[x].min() \
                    else np.array([pts[x].min()])
                ax.plot(xs, c * log_squared(xs), linestyle="--", color=color, linewidth=1)
        ax.set_xscale("log", base=2)
        xticks = sorted(sub[x].unique())
        if xticks:
            ax.set_xticks(xticks)
            ax.set_xticklabels([_plain_number(t) for t in xticks])
        ax.set_title(METHOD_LABELS.get(method, method))
        ax.set_xlabel(xlabel)
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="small", title="fit C (1 + log(H/h))$^2$", title_fontsize="small")
        else:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")
    axes[0][0].set_ylabel("condition number estimate" if y == "cond" else y)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
        plt.close(fig)
    return fits


def _plain_number(value: float) -> str:
    value = float(value)
    return str(int(value)) if value.is_integer() else f"{value:g}"
