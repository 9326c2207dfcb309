"""Scaling study of the contact solvers: time and iterations against the number of dofs.

One case is one contact solver on one mesh of problem (3.1)
(:func:`~ddsolve.scene.contact.two_membranes`, Dostal loads, 1/H = N
subdomains per membrane side, H/h = m elements per subdomain side):

* :func:`run_scaling_case` assembles the problem (not timed: scene, NGSolve
  assembly, :class:`~ddsolve.dd.Substructures`, :class:`~ddsolve.contact.ContactProblem`;
  its time is ``assembly_seconds``) and times the solver from there on, i.e.
  everything the solver does (operators, factorizations, iterations). ddsolve's
  solvers run with one BLAS thread, as :func:`ddsolve.solve` does
  (threadpoolctl); the ``pdas`` reference (primal-dual active set with MKL
  PARDISO face factorizations) runs with ``direct_threads`` threads.
* :func:`fit_exponent` fits t = c n^p by least squares on log t against log n.
* :func:`scaling_table`, :func:`scaling_summary`, :func:`plot_scaling` make the
  report; :func:`profile_case` runs cProfile on one solve.
"""
from __future__ import annotations

import cProfile
import io
import logging
import math
import os
import pstats
import time
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from ddsolve.contact import ContactProblem
from ddsolve.prepared import prepare
from ddsolve.spec import ProblemSpec

from ..report.fits import MIN_FIT_POINTS, r2_text
from ..report.plots import _save
from ..report.rule_sets import DEFAULT, NOTE_MARK, only_sentence
from ..report.tables import NOT_CONVERGED_MARK, NOT_CONVERGED_NOTE, _truthy
from .case import CaseRecord
from .contact import CONTACT_METHODS, solve_contact
from .memory import peak_rss_mb
from .peers import DEFAULT_DIRECT

log = logging.getLogger(__name__)

#: ddsolve's method and the direct reference of the study's comparisons.
DDSOLVE_METHOD = "active-set"
REFERENCE_METHOD = "pdas"


def contact_spec(subdomains: int, elements: int, *, f: str = "dostal", rtol: float = 1e-5,
                 maxiter: int = 1000) -> ProblemSpec:
    """The ProblemSpec of problem (3.1) on N x N subdomains of m x m elements per membrane."""
    return ProblemSpec.from_mapping({"problem": "contact", "subdomains": int(subdomains),
                                     "elements": int(elements), "f": f, "rtol": rtol, "maxiter": maxiter})


def build_contact(spec: ProblemSpec) -> tuple[ContactProblem, float]:
    """Assemble the contact problem of ``spec``; returns it and the wall time it took."""
    t0 = time.perf_counter()
    problem = prepare(spec).contact
    return problem, time.perf_counter() - t0


def run_scaling_case(subdomains: int, elements: int, method: str, *, rtol: float = 1e-5, maxiter: int = 1000,
                     direct: str = DEFAULT_DIRECT, direct_threads: int = 1, blas_threads: int = 1,
                     repeats: int = 1, repeat_budget: float = 30.0, f: str = "dostal") -> CaseRecord:
    """Time one contact solver on one mesh.

    Parameters
    ----------
    subdomains, elements : int
        N = 1/H and m = H/h.
    method : {"active-set", "smalbe", "pdas"}
        See :func:`ddstudies.bench.contact.solve_contact`.
    rtol : float
        Tolerance of the iterative methods (1e-5 as in Chapters 5 and 6).
    maxiter : int
    direct : str
        Backend of the ``pdas`` face factorizations.
    direct_threads : int
        Threads of those factorizations.
    blas_threads : int
        BLAS threads (threadpoolctl) around every solve; 1 as in :func:`ddsolve.solve`.
    repeats : int
        At most this many solves; the best wall time is kept.
    repeat_budget : float
        No further repeat starts once the solves have taken this many seconds
        (large cases run once).
    f : str
        Load of the spec (``dostal``: the benchmark's patch loads).

    Returns
    -------
    CaseRecord
        ``values``: problem, method, bodies, subdomains, elements, ndof,
        n_contact, converged, reason, iterations (active set: PCR iterations of
        all face solves; SMALBE: MPRGP steps; pdas: face solves), outer_iterations,
        pcg_iterations, inner_iterations (list), n_factorizations,
        wall_seconds (best), cpu_seconds (process CPU time of that solve),
        setup_seconds, assembly_seconds, kkt_residual, energy, n_active,
        peak_rss_mb, repeats_done, blas_threads, direct_backend and
        direct_threads (of pdas; "" and 0 for the other methods, which read
        neither), threads (the method's: direct_threads for pdas,
        blas_threads otherwise), cpu_count.
    """
    if method not in CONTACT_METHODS:
        raise ValueError(f"unknown contact method {method!r} (choose from {', '.join(CONTACT_METHODS)})")
    spec = contact_spec(subdomains, elements, f=f, rtol=rtol, maxiter=maxiter)
    with threadpool_limits(limits=blas_threads, user_api="blas"):
        problem, assembly = build_contact(spec)
        log.info("contact N=%d m=%d: %d dofs, %d pairs, assembly %.2f s", subdomains, elements, problem.ndof,
                 problem.n_contact, assembly)
        best, best_cpu, sol, spent, done = math.inf, math.nan, None, 0.0, 0
        while done < max(int(repeats), 1) and (done == 0 or spent < repeat_budget):
            t0, c0 = time.perf_counter(), time.process_time()
            run = solve_contact(method, problem, rtol=rtol, maxiter=maxiter, direct=direct, threads=direct_threads)
            seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
            spent += seconds
            done += 1
            if seconds < best:
                best, best_cpu, sol = seconds, cpu, run
            log.info("%s run %d: %.3f s wall, %.3f s CPU (%s)", method, done, seconds, cpu, run.reason)
    assert sol is not None
    kkt = problem.kkt(sol.u, sol.lam)
    iterations = sol.outer_iterations if method == "pdas" else sol.total_iterations
    values: dict[str, Any] = {
        "problem": "contact", "method": method, "bodies": 2, "subdomains": int(subdomains),
        "elements": int(elements), "ndof": int(problem.ndof), "n_contact": int(problem.n_contact),
        "converged": bool(sol.converged), "reason": str(sol.reason), "iterations": int(iterations),
        "outer_iterations": int(sol.outer_iterations), "pcg_iterations": int(sol.pcg_iterations),
        "inner_iterations": [int(k) for k in sol.inner_iterations],
        "n_factorizations": int(sol.n_factorizations), "wall_seconds": float(best),
        "cpu_seconds": float(best_cpu), "setup_seconds": float(sol.extra.get("setup_seconds", 0.0)),
        "assembly_seconds": float(assembly), "kkt_residual": float(kkt.max),
        "energy": float(problem.energy(sol.u)), "n_active": int(np.count_nonzero(sol.lam > 0)),
        "peak_rss_mb": float(peak_rss_mb()), "repeats_done": int(done), "blas_threads": int(blas_threads),
        "direct_backend": direct if method == REFERENCE_METHOD else "",
        "direct_threads": int(direct_threads) if method == REFERENCE_METHOD else 0,
        "threads": int(direct_threads if method == "pdas" else blas_threads), "cpu_count": int(os.cpu_count() or 0),
    }
    log.info("%s N=%d m=%d (%d dofs): %.3f s, %d iterations, KKT %.1e", method, subdomains, elements,
             problem.ndof, best, iterations, kkt.max)
    return CaseRecord(values)


#: The solver options of a scaling case and their types (``params.options`` of the workflow's jobs).
SOLVER_OPTIONS = {"rtol": float, "maxiter": int, "direct": str, "direct_threads": int}


def solver_options(options: dict[str, Any]) -> dict[str, Any]:
    """The entries of ``options`` that are :data:`SOLVER_OPTIONS`, cast to their types (a job's params hold
    only the options its method reads; the others keep :func:`run_scaling_case`'s defaults)."""
    return {key: cast(options[key]) for key, cast in SOLVER_OPTIONS.items() if key in options}


def case_params(subdomains: int, elements: int, method: str, *, rtol: float = 1e-5, maxiter: int = 1000,
                repeats: int = 1, f: str = "dostal") -> dict[str, Any]:
    """``/params`` of a case file: the spec (``method`` the study's name) plus ``repeats``; ``rtol`` and
    ``maxiter`` None for the direct reference, which reads neither."""
    spec = contact_spec(subdomains, elements, f=f, rtol=rtol, maxiter=maxiter)
    direct = method == REFERENCE_METHOD
    return {**spec.to_dict(), "method": method, "rtol": None if direct else rtol,
            "maxiter": None if direct else maxiter, "repeats": int(repeats)}


@dataclass(frozen=True)
class ExponentFit:
    """Least-squares fit log t = log c + p log n.

    Attributes
    ----------
    exponent : float
        p.
    prefactor : float
        c (seconds at n = 1).
    r2 : float
        Coefficient of determination of the log-log fit.
    n_points : int
    """

    exponent: float
    prefactor: float
    r2: float
    n_points: int

    def predict(self, n: np.ndarray | float) -> np.ndarray:
        """c n^p."""
        return self.prefactor * np.asarray(n, dtype=float) ** self.exponent


def fit_exponent(ndof: Sequence[float], seconds: Sequence[float]) -> ExponentFit:
    """Fit t = c n^p by linear least squares on (log n, log t).

    Parameters
    ----------
    ndof, seconds : sequence of float
        Sizes and times (positive); non-finite or non-positive pairs are dropped.

    Returns
    -------
    ExponentFit

    Raises
    ------
    ValueError
        Fewer than two usable points or a single distinct size.
    """
    n = np.asarray(ndof, dtype=float)
    t = np.asarray(seconds, dtype=float)
    keep = np.isfinite(n) & np.isfinite(t) & (n > 0) & (t > 0)
    n, t = n[keep], t[keep]
    if n.size < 2 or np.unique(n).size < 2:
        raise ValueError("fit_exponent needs at least two distinct positive sizes")
    x, y = np.log(n), np.log(t)
    p, logc = np.polyfit(x, y, 1)
    resid = y - (logc + p * x)
    total = float(((y - y.mean()) ** 2).sum())
    r2 = 1.0 - float((resid ** 2).sum()) / total if total > 0 else 1.0
    return ExponentFit(exponent=float(p), prefactor=float(math.exp(logc)), r2=r2, n_points=int(n.size))


def scaling_table(df: pd.DataFrame, methods: Sequence[str] | None = None) -> pd.DataFrame:
    """One row per mesh: N, H/h, ndof, then per method its wall time, CPU time and iterations,
    and ``ratio`` = ddsolve / direct wall time.

    Parameters
    ----------
    df : DataFrame
        Collected case files (:func:`ddstudies.aggregate.collect`).
    methods : sequence of str, optional
        Methods in column order (default: those in ``df``, in order of appearance).
    """
    methods = list(methods) if methods is not None else list(dict.fromkeys(df["method"]))
    rows = []
    for (ns, m), group in df.groupby(["subdomains", "elements"], sort=False):
        row: dict[str, Any] = {"subdomains": int(ns), "elements": int(m), "ndof": int(group["ndof"].iloc[0])}
        for method in methods:
            sel = group[group["method"] == method]
            get = (lambda col: sel[col].iloc[0] if len(sel) and col in sel else np.nan)
            row[f"{method}_seconds"] = float(get("wall_seconds"))
            row[f"{method}_cpu_seconds"] = float(get("cpu_seconds"))
            row[f"{method}_iterations"] = get("iterations")
            row[f"{method}_outer"] = get("outer_iterations")
            row[f"{method}_converged"] = get("converged")
        if DDSOLVE_METHOD in methods and REFERENCE_METHOD in methods:
            both = all(_truthy(row[f"{m}_converged"]) for m in (DDSOLVE_METHOD, REFERENCE_METHOD))
            # a run that did not converge is no time to compare with (nor to judge a target by)
            row["ratio"] = (row[f"{DDSOLVE_METHOD}_seconds"] / row[f"{REFERENCE_METHOD}_seconds"] if both
                            else math.nan)
        rows.append(row)
    return pd.DataFrame(rows).sort_values("ndof").reset_index(drop=True)


def fits_by_method(df: pd.DataFrame, *, column: str = "wall_seconds") -> dict[str, ExponentFit]:
    """:func:`fit_exponent` of ``column`` against ndof for every method with two or more sizes, over its runs
    that converged (a run stopped at maxiter or rejected is no point of a growth law)."""
    out = {}
    if "converged" in df:
        df = df[[_truthy(c) for c in df["converged"]]]
    for method, rows in df.groupby("method", sort=False):
        try:
            out[str(method)] = fit_exponent(rows["ndof"], rows[column])
        except ValueError:
            continue
    return out


def _ratio_at(table: pd.DataFrame, ndof: int) -> float:
    sel = table[table["ndof"] == ndof]
    return float(sel["ratio"].iloc[0]) if len(sel) and "ratio" in sel else math.nan


def scaling_summary(df: pd.DataFrame, targets: Mapping[str, float] | None = None) -> dict[str, Any]:
    """Exponents, ddsolve/direct ratios and the issue's targets.

    Parameters
    ----------
    df : DataFrame
        Collected case files.
    targets : mapping, optional
        ``ratio_at_ndof`` (321201), ``max_ratio`` (1.5), ``large_ndof``
        (1e6: ddsolve faster than direct from there on), ``max_exponent`` (1.15).

    Returns
    -------
    dict
        ``fits`` (method -> ExponentFit), ``table`` (:func:`scaling_table`),
        ``ratio_at`` (ratio at ``ratio_at_ndof``), ``largest_ndof``,
        ``ratio_largest``, and ``targets``: a list of (name, measured, met) rows.
    """
    t = {"ratio_at_ndof": 321201, "max_ratio": 1.5, "large_ndof": 1_000_000, "max_exponent": 1.15,
         **dict(targets or {})}
    fits = fits_by_method(df)
    table = scaling_table(df)
    largest = int(table["ndof"].max())
    ratio_at = _ratio_at(table, int(t["ratio_at_ndof"]))
    ratio_largest = _ratio_at(table, largest)
    large = table[table["ndof"] >= t["large_ndof"]]
    checks: list[tuple[str, str, bool | None]] = []
    checks.append((f"{DDSOLVE_METHOD} time at {int(t['ratio_at_ndof'])} dofs <= {t['max_ratio']:g} x direct",
                   f"{ratio_at:.2f} x" if math.isfinite(ratio_at) else "n/a (no direct run at that size)",
                   bool(ratio_at <= t["max_ratio"]) if math.isfinite(ratio_at) else None))
    if len(large) and "ratio" in large:
        faster = bool((large["ratio"] < 1.0).all())
        measured = ", ".join(f"{r:.2f} x at {n}" for n, r in zip(large["ndof"], large["ratio"]))
    else:
        faster, measured = None, "no case with that many dofs"
    checks.append((f"{DDSOLVE_METHOD} faster than direct at >= {int(t['large_ndof'])} dofs", measured, faster))
    fit = fits.get(DDSOLVE_METHOD)
    # a verdict needs a growth law: MIN_FIT_POINTS sizes (two fit any exponent exactly) and a time that grows
    # (one falling with the size is the noise of tiny cases); as the unstructured study's targets (a review)
    note = "" if fit is None else (f" (not a growth law: {fit.n_points} sizes)" if fit.n_points < MIN_FIT_POINTS
                                   else "" if fit.exponent > 0 else " (not a growth law: sizes too small)")
    checks.append((f"{DDSOLVE_METHOD} time grows no faster than dofs^{t['max_exponent']:g}",
                   f"dofs^{fit.exponent:.3f}{note}" if fit else "no fit",
                   bool(fit.exponent <= t["max_exponent"]) if fit is not None and not note else None))
    return {"fits": fits, "table": table, "ratio_at": ratio_at, "largest_ndof": largest,
            "ratio_largest": ratio_largest, "targets": checks, "target_values": t}


def summary_markdown(summary: Mapping[str, Any], *, title: str = "Scaling of the contact solvers") -> str:
    """The report of :func:`scaling_summary` as Markdown: table, fits, targets."""
    table: pd.DataFrame = summary["table"]
    methods = [c[: -len("_seconds")] for c in table.columns
               if c.endswith("_seconds") and not c.endswith("_cpu_seconds")]
    head = ["N", "H/h", "dofs"] + [f"{m} [s]" for m in methods] + [f"{m} it (outer)" for m in methods]
    if "ratio" in table:
        head.append(f"{DDSOLVE_METHOD} / {REFERENCE_METHOD}")
    lines = [f"# {title}", "", f"{NOTE_MARK} {only_sentence(DEFAULT)}", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, row in table.iterrows():
        cells = [str(int(row["subdomains"])), str(int(row["elements"])), f"{int(row['ndof']):,}"]
        cells += [f"{row[f'{m}_seconds']:.3f}" for m in methods]
        cells += [f"{_int(row[f'{m}_iterations'])} ({_int(row[f'{m}_outer'])})"
                  + (NOT_CONVERGED_MARK if _failed(row, m) else "") for m in methods]
        if "ratio" in table:
            cells.append(f"{row['ratio']:.2f}" if pd.notna(row["ratio"]) else "n/a")
        lines.append("| " + " | ".join(cells) + " |")
    if any(_failed(row, m) for _, row in table.iterrows() for m in methods):
        lines += ["", f"{NOT_CONVERGED_MARK} {NOT_CONVERGED_NOTE}; left out of the fits and the ratios."]
    lines += ["", "Least-squares fit of log(time) against log(dofs), runs that converged:", ""]
    lines += [f"- {m}: time ~ {fit.prefactor:.3g} s x dofs^{fit.exponent:.3f} "
              + (f"(R^2 = {r2_text(fit.r2, fit.n_points, spec='.4f')}, {fit.n_points} sizes)" if fit.n_points > 2
                 else f"({r2_text(fit.r2, fit.n_points).replace('points', 'sizes')}, no R^2)")
              for m, fit in summary["fits"].items()]
    def ratio(value: float) -> str:
        return f"{value:.2f}" if math.isfinite(value) else "n/a (no runs of both methods at that size)"

    lines += ["", f"ddsolve / direct at {int(summary['target_values']['ratio_at_ndof'])} dofs: "
              f"{ratio(summary['ratio_at'])}; at the largest size ({summary['largest_ndof']:,} dofs): "
              f"{ratio(summary['ratio_largest'])}", "", "| target | measured | met |", "|---|---|---|"]
    for name, measured, met in summary["targets"]:
        lines.append(f"| {name} | {measured} | {'n/a' if met is None else ('yes' if met else 'no')} |")
    return "\n".join(lines) + "\n"


def _failed(row: pd.Series, method: str) -> bool:
    """Whether the table row holds a run of ``method`` that did not converge (a missing run is not one)."""
    flag = row.get(f"{method}_converged", np.nan)
    return not (isinstance(flag, float) and math.isnan(flag)) and not _truthy(flag)


def _int(value: Any) -> str:
    try:
        return str(int(value))
    except (TypeError, ValueError):
        return "-"


_STYLES = {"active-set": ("tab:blue", "o", "-"), "smalbe": ("tab:green", "^", "-"),
           "pdas": ("tab:red", "s", "--")}
_LABELS = {"active-set": "ddsolve: active set + hybrid (1 BLAS thread)",
           "smalbe": "ddsolve: SMALBE/MPRGP (1 BLAS thread)",
           "pdas": "direct: PDAS + {backend} ({threads} thread{s})"}


def plot_scaling(df: pd.DataFrame, path: str | os.PathLike | None, *, title: str | None = None):
    """Wall time against dofs (log-log), one line per method with its fitted exponent in the legend.

    Parameters
    ----------
    df : DataFrame
        Collected case files (``method``, ``ndof``, ``wall_seconds``, ``direct_backend``,
        ``direct_threads``, ``converged``).
    path : path-like or None
        PNG to write (the figure is returned and left open when None).
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fits = fits_by_method(df)
    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    for method, rows in df.groupby("method", sort=False):
        rows = rows.sort_values("ndof")
        color, marker, style = _STYLES.get(str(method), ("tab:gray", "x", ":"))
        threads = int(rows["direct_threads"].iloc[0]) if "direct_threads" in rows else 1
        label = _LABELS.get(str(method), str(method)).format(
            backend=str(rows["direct_backend"].iloc[0]) if "direct_backend" in rows else "direct",
            threads=threads, s="" if threads == 1 else "s")
        n = rows["ndof"].to_numpy(dtype=float)
        t = rows["wall_seconds"].to_numpy(dtype=float)
        fit = fits.get(str(method))
        if fit is not None:
            label += f", fit dofs^{fit.exponent:.2f}"
            grid = np.geomspace(n.min(), n.max(), 50)
            ax.plot(grid, fit.predict(grid), color=color, linestyle=":", linewidth=1)
        ax.plot(n, t, marker=marker, linestyle=style, color=color, label=label)
        bad = ~rows["converged"].astype(bool).to_numpy() if "converged" in rows else np.zeros(n.size, bool)
        if bad.any():
            ax.plot(n[bad], t[bad], "x", color="black", markersize=10)
    n_all = df["ndof"].to_numpy(dtype=float)
    if n_all.size:
        ref_n = np.array([n_all.min(), n_all.max()])
        t0 = float(df.loc[df["ndof"] == n_all.min(), "wall_seconds"].min())
        ax.plot(ref_n, t0 * (ref_n / ref_n[0]), color="gray", linestyle="-.", linewidth=0.8, label="dofs^1")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("degrees of freedom")
    ax.set_ylabel("wall time of setup + solve [s] (assembly excluded)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    if title is None:
        sizes = sorted({int(v) for v in df["subdomains"]}) if "subdomains" in df else []
        title = ("Contact problem (3.1), N = " + ", ".join(map(str, sizes)) + " subdomains per membrane side"
                 if sizes else "Contact problem (3.1)")
    ax.set_title(title)
    fig.tight_layout()
    _save(fig, path)
    return fig


def profile_case(subdomains: int, elements: int, method: str = DDSOLVE_METHOD, *, rtol: float = 1e-5,
                 maxiter: int = 1000, direct: str = DEFAULT_DIRECT, direct_threads: int = 1,
                 blas_threads: int = 1, top: int = 30, sort: Iterable[str] = ("tottime", "cumulative"),
                 stats_path: str | os.PathLike | None = None) -> str:
    """cProfile one solve (assembly excluded) and return the top functions as text.

    Parameters
    ----------
    subdomains, elements, method, rtol, maxiter, direct, direct_threads, blas_threads
        As :func:`run_scaling_case`.
    top : int
        Functions listed per sort key.
    sort : iterable of str
        pstats sort keys, one listing each.
    stats_path : path-like, optional
        Also dump the raw statistics there (``pstats.Stats(path)``).

    Returns
    -------
    str
        A header (size, assembly time, wall time of the profiled solve, which
        includes the profiler's overhead, and the solver's outcome) and the
        listings.
    """
    spec = contact_spec(subdomains, elements, rtol=rtol, maxiter=maxiter)
    with threadpool_limits(limits=blas_threads, user_api="blas"):
        problem, assembly = build_contact(spec)
        profiler = cProfile.Profile()
        t0 = time.perf_counter()
        profiler.enable()
        sol = solve_contact(method, problem, rtol=rtol, maxiter=maxiter, direct=direct, threads=direct_threads)
        profiler.disable()
        seconds = time.perf_counter() - t0
    if stats_path is not None:
        profiler.dump_stats(os.fspath(stats_path))
    out = io.StringIO()
    out.write(f"cProfile of {method}, N = {subdomains}, H/h = {elements}: {problem.ndof} dofs, "
              f"{problem.n_contact} contact pairs\n")
    out.write(f"assembly (not profiled) {assembly:.2f} s; profiled solve {seconds:.2f} s wall "
              f"(profiler overhead included); {sol.reason}; {sol.total_iterations} inner iterations, "
              f"{sol.outer_iterations} outer\n")
    for key in sort:
        out.write(f"\n==== top {top} by {key} ====\n")
        stats = pstats.Stats(profiler, stream=out)
        stats.strip_dirs().sort_stats(key).print_stats(top)
    return out.getvalue()
