"""Work-precision summary table and plot.

:func:`summary_table` reduces the collected case rows
(:func:`ddstudies.aggregate.collect`) to one row per (problem, method,
rtol) with the time, its ratio to the direct solve, both errors and memory.
:func:`plot_work_precision` draws time / direct time (wall or CPU) against
the error, one line per (problem, method) ordered by rtol, the peers dashed; the left panel
uses the algebraic error, the right one the total error against the 2x
refined solution (the discretization error of each problem is a dotted
vertical line there).

Uses the non-interactive Agg backend.
"""
from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from ..report.plots import _save, label_narrow_log_axis

#: Columns of the summary, in order.
SUMMARY_COLUMNS: tuple[str, ...] = (
    "problem", "method", "peer", "rtol", "ndof", "converged", "iterations", "wall_seconds",
    "setup_seconds", "direct_seconds", "time_ratio", "cpu_seconds", "direct_cpu_seconds", "cpu_ratio",
    "algebraic_error", "total_error",
    "discretization_error", "mem_mb", "peak_rss_mb", "direct_backend",
    "l2_error", "lambda_error", "kkt_residual",
)

#: Floor for errors that are exactly zero on a log axis.
ERROR_FLOOR = 1e-16

_MARKERS = {"poisson": "o", "multibody": "s", "contact": "D"}


def summary_table(df: pd.DataFrame) -> pd.DataFrame:
    """One row per case, sorted by problem, method and decreasing rtol; the columns of :data:`SUMMARY_COLUMNS`."""
    out = df.copy()
    for col in SUMMARY_COLUMNS:
        if col not in out.columns:
            out[col] = np.nan
    out = out[list(SUMMARY_COLUMNS)]
    out = out.assign(_r=out["rtol"].fillna(0.0)).sort_values(["problem", "method", "_r"], ascending=[True, True, False])
    return out.drop(columns="_r").reset_index(drop=True)


#: Time measures of the plot: ratio column and axis label.
TIME_KINDS: dict[str, tuple[str, str]] = {
    "wall": ("time_ratio", "wall time / {backend} direct wall time (same job)"),
    "cpu": ("cpu_ratio", "CPU time / {backend} direct CPU time (same job)"),
}


def plot_work_precision(df: pd.DataFrame, path: str | os.PathLike | None, *, time: str = "wall",
                        title: str | None = None):
    """Time / direct time against algebraic error (left) and total error (right).

    Parameters
    ----------
    df : DataFrame
        :func:`summary_table` rows (or anything with its columns).
    path : path-like or None
        PNG to write (the figure is returned and left open when None).
    time : {"wall", "cpu"}
        Plot the wall-time ratio ``time_ratio`` or the CPU-time ratio
        ``cpu_ratio`` (less sensitive to other processes on a shared machine).
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    if time not in TIME_KINDS:
        raise ValueError(f"time must be one of {', '.join(TIME_KINDS)}, got {time!r}")
    ratio_column, ylabel = TIME_KINDS[time]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharey=True)
    methods = list(dict.fromkeys(df["method"]))
    colors = {m: plt.cm.tab10(i % 10) for i, m in enumerate(methods)}
    kinds = (("algebraic_error", "algebraic error $\\|u - u_h\\|_A / \\|u_h\\|_A$"),
             ("total_error", "total error $\\|u_{h/2} - u\\|_{A_{h/2}} / \\|u_{h/2}\\|_{A_{h/2}}$"))
    for ax, (column, label) in zip(axes, kinds):
        for (problem, method), rows in df.groupby(["problem", "method"], sort=False):
            rows = rows.assign(_r=rows["rtol"].fillna(0.0)).sort_values("_r", ascending=False)
            peer = bool(rows["peer"].iloc[0]) if "peer" in rows else False
            x = np.maximum(rows[column].to_numpy(dtype=float), ERROR_FLOOR)
            y = rows[ratio_column].to_numpy(dtype=float)
            ax.plot(x, y, linestyle="--" if peer else "-", marker=_MARKERS.get(problem, "^"),
                    color=colors[method], markerfacecolor="none" if peer else colors[method],
                    label=f"{problem}: {method}" + (" (peer)" if peer else "")
                    + (" (+ polish where accepted)" if method == "smalbe" else ""))
            bad = ~rows["converged"].astype(bool).to_numpy()
            if bad.any():         # black: red is a method's colour too (a review)
                ax.plot(x[bad], y[bad], "x", color="black", markersize=10)
        if column == "total_error":
            for problem, rows in df.groupby("problem", sort=False):
                ax.axvline(float(rows["discretization_error"].iloc[0]), color="gray", linestyle=":",
                           linewidth=1)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.invert_xaxis()
        ax.set_xlabel(label)
        ax.grid(True, which="both", alpha=0.3)
    # a ratio range within one decade has one labelled tick or none: label round values (the peers near
    # 1.1-1.3 had no label below 2; a review)
    label_narrow_log_axis(axes[0].yaxis, *axes[0].get_ylim())
    backend = str(df["direct_backend"].iloc[0]) if "direct_backend" in df and len(df) else "direct"
    axes[0].set_ylabel(ylabel.format(backend=backend))
    handles, labels = axes[1].get_legend_handles_labels()       # below the panels: it covered data (a review)
    fig.legend(handles, labels, loc="lower center", ncol=min(4, max(len(labels), 1)), fontsize=8, frameon=False)
    kind = "CPU" if time == "cpu" else "wall"
    fig.suptitle(title or f"Work-precision: {kind} time (setup + solve) against error, one point per rtol "
                          "(black x: not converged; dotted: discretization error)")
    fig.tight_layout(rect=(0, 0.04 + 0.04 * ((len(labels) + 3) // 4), 1, 1))
    _save(fig, path)
    return fig
