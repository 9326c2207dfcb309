"""Active set method against SMALBE, made fair: work against the KKT residual reached.

Tables 5.1 / 6.1 compare the two contact methods at one tolerance each, but
the tolerances mean different things (the active set method's inner PCR/PCG
tolerance, SMALBE's epsilon) and the solutions reached differ in accuracy.
This module solves each grid with both methods at several tolerances
(``rtol`` = ``eps``, e.g. 1e-4 .. 1e-8) and under each rule set (ddsolve's
defaults and, where available, the thesis's literal rules, ``preset``), and
records the total iterations, the wall time and the KKT residual reached
(the largest of the four parts of :meth:`ddsolve.contact.ContactProblem.kkt`).

The work compared is ``work_iterations``: the total (inner) iterations of Tables 5.1 / 6.1 plus what
the thesis's count leaves out, the active set method's PCG iterations for its initial guess and
SMALBE's polish (a FETI-FETI PCG solve on its active set, under the default rules; its solution is
then the polish's, so the default SMALBE's accuracy is that of "SMALBE + polish").

The verdict (:func:`verdict`) is computed per rule set: for each grid, the
total iterations each method needs to reach a KKT residual are compared at
matched accuracy (each method's cheapest run whose KKT residual is at most
the target; targets are the KKT residuals both methods reach).

    python -m ddstudies.contact_precision --grid 4,4 --grid 8,4 --rtols 1e-4 1e-6 1e-8 \\
        --out reports/table_5_6/work_precision.md
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from .optimal import _atomic_write

__all__ = ["COLUMNS", "matched_work", "plot_work_precision", "render_markdown", "run_grid", "verdict", "main"]

COLUMNS = ["rule_set", "subdomains", "elements", "method", "rtol", "total_iterations", "extra_iterations",
           "work_iterations", "polished", "seconds", "kkt_residual", "converged"]
METHODS = ("active-set", "smalbe")
LABELS = {"active-set": "active set", "smalbe": "SMALBE"}


def run_grid(subdomains: int, elements: int, rtols: Sequence[float], *, preset: str | None = None,
             maxiter: int = 1000, f: str = "dostal") -> list[dict[str, Any]]:
    """Both methods at every tolerance on one grid; one record per run (keys :data:`COLUMNS`)."""
    from threadpoolctl import threadpool_limits

    from ddsolve.api import SOLVERS      # the registry's contact runners apply the spec's preset
    from ddsolve.prepared import prepare
    from ddsolve.spec import ProblemSpec

    mapping = dict(problem="contact", method="active-set", subdomains=subdomains, elements=elements,
                   f=f, maxiter=maxiter)
    if preset is not None:
        mapping["preset"] = preset
    spec = ProblemSpec.from_mapping(mapping)
    records = []
    with threadpool_limits(1, "blas"):
        prep = prepare(spec)
        for method in METHODS:
            for rtol in rtols:
                run_prep = dataclasses.replace(prep, spec=dataclasses.replace(spec, method=method, rtol=float(rtol)))
                t0 = time.perf_counter()
                sol = SOLVERS["contact"][method](run_prep)
                seconds = time.perf_counter() - t0
                kkt = prep.contact.kkt(sol.u, sol.lam)
                # what the thesis's total leaves out: the initial PCG (active set), the polish (SMALBE)
                extra = int(sol.pcg_iterations) + int(sol.extra.get("polish_iterations", 0) or 0)
                polished = str(sol.extra.get("polish", "")) in ("accepted", "rescued")
                records.append(dict(rule_set=preset or "default", subdomains=subdomains, elements=elements,
                                    method=method, rtol=float(rtol), total_iterations=int(sol.total_iterations),
                                    extra_iterations=extra, work_iterations=int(sol.total_iterations) + extra,
                                    polished=polished, seconds=seconds, kkt_residual=float(kkt.max),
                                    converged=bool(sol.converged)))
    return records


def matched_work(df: pd.DataFrame) -> pd.DataFrame:
    """Per rule set, grid and target KKT residual: each method's least iterations and time reaching it.

    Targets: the KKT residuals reached by any run of the grid that both methods
    reach (a method "reaches" a target when one of its converged runs has a
    KKT residual at most the target). Returns columns rule_set, subdomains,
    elements, target, and ``it <method>``, ``s <method>`` for both methods.
    """
    rows = []
    for (rs, ns, m), g in df.groupby(["rule_set", "subdomains", "elements"], sort=True):
        g = g[g["converged"].astype(bool)]
        best = {meth: g[g["method"] == meth] for meth in METHODS}
        if any(b.empty for b in best.values()):
            continue
        reachable = max(float(b["kkt_residual"].min()) for b in best.values())   # reached by both
        for target in sorted(set(g["kkt_residual"][g["kkt_residual"] >= reachable]), reverse=True):
            row: dict[str, Any] = dict(rule_set=rs, subdomains=ns, elements=m, target=target)
            for meth, b in best.items():
                ok = b[b["kkt_residual"] <= target]
                row[f"it {meth}"] = int(ok["work_iterations"].min())
                row[f"s {meth}"] = float(ok["seconds"].min())
            rows.append(row)
    return pd.DataFrame(rows)


def verdict(df: pd.DataFrame) -> str:
    """Per rule set: which method needs fewer total iterations at matched KKT residual (computed)."""
    mw = matched_work(df)
    if mw.empty:
        return "No grid has converged runs of both methods."
    parts = []
    for rs, g in mw.groupby("rule_set", sort=True):
        a, s = g[f"it {METHODS[0]}"].to_numpy(), g[f"it {METHODS[1]}"].to_numpy()
        grids = g.groupby(["subdomains", "elements"])
        # per grid at its tightest common target
        tight = g.loc[grids["target"].idxmin()]
        fewer_a = int(np.sum(tight[f"it {METHODS[0]}"] < tight[f"it {METHODS[1]}"]))
        fewer_s = int(np.sum(tight[f"it {METHODS[0]}"] > tight[f"it {METHODS[1]}"]))
        winner = ("the active set method" if a.sum() < s.sum() else
                  "SMALBE" if s.sum() < a.sum() else "neither method")
        runs = df[df["rule_set"] == rs]
        failed = runs[~runs["converged"].astype(bool)]
        left_out = ""
        if len(failed):
            who = ", ".join(f"{LABELS.get(m, m)} {n}" for m, n in failed["method"].value_counts().sort_index().items())
            left_out = f"; {len(failed)} of {len(runs)} runs reported not converged are left out ({who})"
        parts.append(
            f"rule set {rs}: {winner} needs fewer iterations (total + initial PCG / polish) at matched KKT residual "
            f"({a.sum():.0f} vs {s.sum():.0f} summed over {len(g)} (grid, target) pairs; at each grid's "
            f"tightest common target the active set method needs fewer on {fewer_a} and SMALBE on "
            f"{fewer_s} of {len(tight)} grids{left_out})")
    return "; ".join(parts) + "."


def render_markdown(df: pd.DataFrame) -> str:
    lines = ["# Active set method against SMALBE: work against the KKT residual reached", "",
             "Each grid (N_sub = N^2 per membrane, H/h) solved by both methods at every tolerance "
             "(rtol: the active set method's inner PCR/PCG tolerance; SMALBE's epsilon), per rule set "
             "(default: ddsolve's rules; a preset name: those rules). KKT: the largest of the four KKT "
             "residual parts of the returned solution. total it.: the inner iterations of Tables 5.1 / 6.1; "
             "+ it.: what that count leaves out (the active set method's PCG for its initial guess, SMALBE's "
             "polish: a FETI-FETI PCG solve on its active set); work it.: their sum, which the verdict "
             "compares. polished: the returned solution is the polish's (its KKT residual is the polish's, "
             "not SMALBE's own).", "",
             "| rule set | N | H/h | method | rtol | total it. | + it. | work it. | polished | time [s] | "
             "KKT residual | converged |",
             "|" + "---|" * 12]
    for r in df.sort_values(["rule_set", "subdomains", "elements", "method", "rtol"],
                            ascending=[True, True, True, True, False]).itertuples():
        lines.append(f"| {r.rule_set} | {r.subdomains} | {r.elements} | {LABELS.get(r.method, r.method)} | "
                     f"{r.rtol:.0e} | {r.total_iterations} | {r.extra_iterations} | {r.work_iterations} | "
                     f"{'yes' if r.polished else 'no'} | {r.seconds:.3g} | {r.kkt_residual:.2e} | "
                     f"{'yes' if r.converged else 'no'} |")
    lines += ["", verdict(df), ""]
    return "\n".join(lines)


def plot_work_precision(df: pd.DataFrame, path: str | Path) -> Path:
    """Work iterations and time against the KKT residual, one line per method, rule set and grid (converged
    runs; a run reported not converged is a hollow marker, not on the line)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    styles = {"default": "-", "thesis": "--"}
    colors = {"active-set": "C0", "smalbe": "C3"}
    markers = "osd^vx+*"
    grids = sorted({(int(a), int(b)) for a, b in zip(df["subdomains"], df["elements"])})
    for (rs, ns, m, meth), g in df.groupby(["rule_set", "subdomains", "elements", "method"], sort=True):
        g = g.sort_values("kkt_residual")
        ok = g["converged"].astype(bool)
        mk = markers[grids.index((int(ns), int(m))) % len(markers)]
        name = "SMALBE + polish" if meth == "smalbe" and g["polished"].astype(bool).any() else LABELS.get(meth, meth)
        label = f"{name}, N={ns}, H/h={m}, {rs} rules ({'solid' if rs == 'default' else 'dashed'})" + (f" ({int((~ok).sum())} not converged: hollow)" if (~ok).any()
                                                     else "")
        for ax, col in zip(axes, ("work_iterations", "seconds")):
            ax.plot(g["kkt_residual"][ok], g[col][ok], styles.get(rs, ":"), marker=mk, color=colors.get(meth, "k"),
                    label=label)
            if (~ok).any():
                ax.plot(g["kkt_residual"][~ok], g[col][~ok], linestyle="none", marker=mk, markerfacecolor="none",
                        color=colors.get(meth, "k"))
    for ax, ylabel in zip(axes, ("iterations (total + initial PCG / polish)", "wall time [s]")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.invert_xaxis()
        ax.set_xlabel("KKT residual reached")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.suptitle("Active set method vs SMALBE: work against accuracy (rtol / eps swept)")
    # long handles: the dashes of the thesis rule set showed in the legend, not hidden behind the marker
    # (the two rule sets' entries looked the same; a review)
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=7, frameon=False, handlelength=5)
    fig.tight_layout(rect=(0, 0.06 + 0.035 * ((len(labels) + 1) // 2), 1, 1))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    tmp.replace(path)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ddstudies.contact_precision", description=__doc__.splitlines()[0])
    p.add_argument("--grid", action="append", required=True, help="N,H/h (repeatable)")
    p.add_argument("--rtols", nargs="+", type=float, default=[1e-4, 1e-5, 1e-6, 1e-7, 1e-8])
    p.add_argument("--presets", nargs="+", default=["default"], help="rule sets; 'default': no preset")
    p.add_argument("--f", default="dostal")
    p.add_argument("--maxiter", type=int, default=1000)
    p.add_argument("--out", required=True, help="markdown; .csv and .png are written beside it")
    args = p.parse_args(argv)
    records = []
    for grid in args.grid:
        ns, m = (int(v) for v in grid.split(","))
        for preset in args.presets:
            records += run_grid(ns, m, args.rtols, preset=None if preset == "default" else preset,
                                maxiter=args.maxiter, f=args.f)
    df = pd.DataFrame(records, columns=COLUMNS)
    out = Path(args.out)
    _atomic_write(out.with_suffix(".csv"), df.to_csv(index=False))
    plot_work_precision(df, out.with_suffix(".png"))
    _atomic_write(out, render_markdown(df))
    return 0


if __name__ == "__main__":
    sys.exit(main())
