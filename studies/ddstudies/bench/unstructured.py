"""Unstructured study: ddsolve's DD methods against direct and AMG peers on METIS-partitioned P1 meshes.

One job is one (problem, refinement) of the series: the netgen mesh of
:func:`ddsolve.scene.unstructured_scene` (``maxh``, ``refine``) split into
``parts`` METIS subdomains per body, assembled once
(:func:`ddsolve.prepared.prepare` with ``scene=``), then every method of the
problem in the same process, one after another (so that the ratios compare
runs of one machine state):

* ``poisson``: ``fetidp``, ``bddc`` (ddsolve, 1 BLAS thread as :func:`ddsolve.solve`),
  the direct peers ``sparsecholesky``, ``pardiso`` (NGSolve), ``mkl-pardiso``,
  ``superlu`` and ``pyamg`` (smoothed aggregation + CG), all on the assembled
  matrix R^T diag(A^(i)) R of :meth:`~ddsolve.dd.Substructures.global_matrix`;
* ``contact``: ``active-set`` (active set method with the hybrid face solves),
  ``smalbe`` and ``pdas`` (primal-dual active set with the ``direct`` backend's
  face factorizations, :func:`ddsolve.contact.solve_contact_direct`).

Times (wall, :func:`time.perf_counter`): a DD method's ``seconds`` is
``partition_seconds`` (METIS and its repair, from
:data:`ddsolve.scene.unstructured.LAST_TIMINGS`) + ``substructure_seconds``
(:class:`~ddsolve.dd.Substructures`, the contact problem) + the solver's setup
and solve; a direct peer's ``seconds`` is factorization + solve of the assembled
matrix (its assembly from the subdomain matrices is reported apart as
``global_matrix_seconds``); ``pyamg``: hierarchy + CG. Meshing and NGSolve
assembly are common to all and reported as ``mesh_seconds``/``assembly_seconds``.
``ratio`` is ``seconds`` over that of the problem's reference peer in the same
job (:data:`REFERENCE`; the fastest direct method of the job when it is
missing). Peak memory: ``peak_mb`` the process's peak resident size during the
method (reset before it through ``/proc/self/clear_refs`` where Linux allows),
``added_mb`` its increase over the resident size before it. ``cpu_seconds``:
process CPU time of the method's own call (DD: setup and solve, without the
partition and substructuring), and ``cpu_ratio`` its ratio to the reference's:
on a shared, loaded machine the CPU times are the steadier comparison. The
call also holds what the wall time leaves out (the BLAS thread-pool set-up, a
peer's matrix conversion; the peers are imported before it), so on cases of
under about 0.1 s ``cpu_seconds`` can exceed ``seconds`` (a review: pyamg 0.041 s
CPU against 0.017 s wall at 96 dofs); compare CPU times on larger cases.
"""
from __future__ import annotations

import importlib
import logging
import math
import os
import time
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from ..report.fits import MIN_FIT_POINTS, r2_text
from ..report.plots import _save
from ..report.rule_sets import DEFAULT, NOTE_MARK, only_sentence
from .memory import current_rss_mb, peak_rss_mb
from .scaling import ExponentFit, fit_exponent

log = logging.getLogger(__name__)

#: ddsolve's methods per problem.
DD_METHODS: dict[str, tuple[str, ...]] = {"poisson": ("fetidp", "bddc"), "contact": ("active-set", "smalbe")}
#: Peers per problem (direct backends of ddstudies.bench.peers, pyamg; pdas for contact).
PEER_METHODS: dict[str, tuple[str, ...]] = {
    "poisson": ("sparsecholesky", "pardiso", "mkl-pardiso", "superlu", "pyamg"), "contact": ("pdas",)}
#: Every method of each problem.
METHODS: dict[str, tuple[str, ...]] = {p: DD_METHODS[p] + PEER_METHODS[p] for p in DD_METHODS}
#: The target's reference of each problem: the ratios divide by its time in the same job.
REFERENCE: dict[str, str] = {"poisson": "fastest-direct", "contact": "pdas"}
#: Direct backends (their times form the Poisson reference "fastest-direct").
DIRECT = ("sparsecholesky", "pardiso", "mkl-pardiso", "superlu", "cholmod")


def _reset_peak() -> bool:
    """Reset this process's peak resident size to the current one (Linux >= 4.0); whether it worked."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _peak_mb() -> float:
    """Peak resident size since the last reset (VmHWM), in MiB; ru_maxrss where /proc is missing."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return peak_rss_mb()


def parts_for(refine: Sequence[int], parts: Sequence[int] | int) -> dict[int, int]:
    """METIS parts of each refinement: one number for all, or a list aligned with ``refine``."""
    refine = [int(r) for r in refine]
    if isinstance(parts, (int, np.integer)):
        return {r: int(parts) for r in refine}
    parts = [int(p) for p in parts]
    if len(parts) != len(refine):
        raise ValueError(f"parts: {len(parts)} values for {len(refine)} refinements")
    return dict(zip(refine, parts))


def case_methods(methods: Sequence[str], refine: int, max_refine: Mapping[str, int] | None = None) -> list[str]:
    """The methods run at ``refine``: those without a ``max_refine`` at or above it."""
    max_refine = dict(max_refine or {})
    return [m for m in methods if int(refine) <= int(max_refine.get(m, 10 ** 9))]


def run_unstructured_case(problem: str, *, maxh: float, refine: int, parts: int, methods: Sequence[str],
                          rtol: float = 1e-8, maxiter: int = 1000, cond: bool = True,
                          direct: str = "mkl-pardiso", direct_threads: int = 1, seed: int = 0) -> pd.DataFrame:
    """Build one unstructured problem and run ``methods`` on it; one row per method.

    Parameters
    ----------
    problem : {"poisson", "contact"}
    maxh, refine, parts, seed
        As in :func:`ddsolve.scene.unstructured_scene` (``parts`` per body).
    methods : sequence of str
        Of :data:`METHODS` ``[problem]``; unavailable peers give a row with ``error``.
    rtol, maxiter, cond
        Of the DD methods (Poisson: PCG rtol and Lanczos condition estimate;
        contact: the active set/SMALBE tolerance) and of pyamg + CG.
    direct, direct_threads
        Backend and threads of the ``pdas`` face factorizations.

    Returns
    -------
    DataFrame
        Columns: problem, method, kind (dd, direct, amg), maxh, refine, parts,
        ndof, n_sub, converged, iterations, cond, seconds, setup_seconds,
        solve_seconds, partition_seconds, substructure_seconds, mesh_seconds,
        split_seconds, assembly_seconds, global_matrix_seconds, peak_mb, added_mb,
        cpu_seconds, error (relative 2-norm difference to the reference peer's solution), reason,
        load (1-minute load average at the start of the method), cpu_count.
    """
    from ddsolve.prepared import prepare
    from ddsolve.scene import unstructured as unstructured_mod

    unknown = [m for m in methods if m not in METHODS[problem]]
    if unknown:
        raise ValueError(f"{problem}: unknown methods {unknown} (choose from {list(METHODS[problem])})")
    with threadpool_limits(limits=1, user_api="blas"):
        t0 = time.perf_counter()
        scene = unstructured_mod.unstructured_scene(problem, maxh=maxh, refine=refine, parts=parts, seed=seed)
        scene_seconds = time.perf_counter() - t0
        timings = dict(unstructured_mod.LAST_TIMINGS)
        prep = prepare({"problem": problem, "method": DD_METHODS[problem][0],
                        "rtol": rtol, "maxiter": maxiter, "cond": bool(cond and problem == "poisson")},
                       scene=scene)
    common: dict[str, Any] = {
        "problem": problem, "maxh": float(maxh), "refine": int(refine), "parts": int(parts),
        "ndof": int(prep.sub.ndof), "n_sub": int(prep.sub.n_sub), "mesh_seconds": float(timings.get("mesh", 0.0)),
        "split_seconds": float(timings.get("split", 0.0)), "scene_seconds": float(scene_seconds),
        "assembly_seconds": float(prep.timings.get("assembly", 0.0)),
        "partition_seconds": float(timings.get("partition", 0.0)),
        "substructure_seconds": float(prep.timings.get("substructures", 0.0) + prep.timings.get("contact", 0.0)),
        "cpu_count": int(os.cpu_count() or 0)}
    log.info("%s maxh=%g refine=%d parts=%d: %d dofs, %d subdomains (scene %.2f s, assembly %.2f s)", problem,
             maxh, refine, parts, common["ndof"], common["n_sub"], scene_seconds, common["assembly_seconds"])
    A = b = None
    if problem == "poisson":
        t0 = time.perf_counter()
        A = prep.sub.global_matrix().tocsr()
        b = prep.sub.assemble_vector(prep.sub.f_W)
        common["global_matrix_seconds"] = time.perf_counter() - t0
    rows, solutions = [], {}
    for method in methods:
        row = dict(common, method=method, kind="dd" if method in DD_METHODS[problem]
                   else ("amg" if method == "pyamg" else "direct"), load=float(os.getloadavg()[0]))
        _import_peer(method)            # its first import is not the method's CPU time (pyamg: 0.07 s)
        base = current_rss_mb()
        _reset_peak()
        cpu0 = time.process_time()
        try:
            u = (_run_poisson(method, prep, A, b, rtol, maxiter, cond, row) if problem == "poisson"
                 else _run_contact(method, prep, rtol, maxiter, direct, direct_threads, row))
            solutions[method] = u
        except ImportError as exc:          # an unavailable peer (BackendUnavailable)
            row.update(converged=False, reason=f"unavailable: {exc}")
        row["cpu_seconds"] = time.process_time() - cpu0
        peak = _peak_mb()
        row.update(peak_mb=peak, added_mb=max(peak - base, 0.0))
        log.info("%s: %.3f s, %s iterations (%s), peak %.0f MiB", method, row.get("seconds", math.nan),
                 row.get("iterations"), row.get("reason"), peak)
        rows.append(row)
    df = pd.DataFrame(rows)
    ref = reference_method(df)
    if ref is not None and ref in solutions:
        u_ref = solutions[ref]
        scale = float(np.linalg.norm(u_ref)) or 1.0
        df["error"] = [float(np.linalg.norm(solutions[m] - u_ref) / scale) if m in solutions else math.nan
                       for m in df["method"]]
    return df


def _import_peer(method: str) -> None:
    """Import the package of a peer that ddsolve does not load itself (pyamg; a missing one is reported later)."""
    if method == "pyamg":
        try:
            importlib.import_module("pyamg")
        except ImportError:
            pass


def _run_poisson(method: str, prep: Any, A: Any, b: np.ndarray, rtol: float, maxiter: int, cond: bool,
                 row: dict) -> np.ndarray:
    from ddsolve.api import SOLVERS
    from ddsolve.krylov import attained

    from .peers import direct_solver, pyamg_cg

    if method in DD_METHODS["poisson"]:
        with threadpool_limits(limits=1, user_api="blas"):
            t0 = time.perf_counter()
            out = SOLVERS["poisson"][method](prep).output
            seconds = time.perf_counter() - t0
        kr = out.krylov
        converged, reason = attained(kr, rtol)
        row.update(seconds=seconds + row["partition_seconds"] + row["substructure_seconds"],
                   setup_seconds=out.setup_seconds, solve_seconds=seconds - out.setup_seconds,
                   iterations=int(kr.iterations), converged=bool(converged), reason=str(reason),
                   cond=float(kr.cond) if cond and kr.cond is not None else math.nan)
        return prep.sub.assemble_vector(out.u) if out.u.size != A.shape[0] else out.u
    if method == "pyamg":
        res = pyamg_cg(A, b, rtol, maxiter=maxiter)
        row.update(seconds=res.setup_seconds + res.solve_seconds, setup_seconds=res.setup_seconds,
                   solve_seconds=res.solve_seconds, iterations=int(res.iterations), converged=bool(res.converged),
                   reason="converged" if res.converged else "not converged")
        return res.x
    factor_seconds, solve = direct_solver(method, A)
    t0 = time.perf_counter()
    u = solve(b)
    seconds = time.perf_counter() - t0
    row.update(seconds=factor_seconds + seconds, setup_seconds=factor_seconds, solve_seconds=seconds,
               iterations=0, converged=bool(np.all(np.isfinite(u))), reason="direct solve")
    return u


def _run_contact(method: str, prep: Any, rtol: float, maxiter: int, direct: str, direct_threads: int,
                 row: dict) -> np.ndarray:
    from .contact import solve_contact

    problem = prep.contact
    with threadpool_limits(limits=1, user_api="blas"):
        t0 = time.perf_counter()
        sol = solve_contact(method, problem, rtol=rtol, maxiter=maxiter, direct=direct, threads=direct_threads)
        seconds = time.perf_counter() - t0
    kkt = problem.kkt(sol.u, sol.lam)
    setup = float(sol.extra.get("setup_seconds", 0.0))
    dd = method in DD_METHODS["contact"]
    row.update(seconds=seconds + (row["partition_seconds"] + row["substructure_seconds"] if dd else 0.0),
               setup_seconds=setup, solve_seconds=seconds - setup,
               iterations=int(sol.outer_iterations if method == "pdas" else sol.total_iterations),
               converged=bool(sol.converged), reason=str(sol.reason), cond=math.nan,
               kkt_residual=float(kkt.max), n_active=int(np.count_nonzero(sol.lam > 0)),
               direct_backend=direct if method == "pdas" else "")
    return np.asarray(sol.u, dtype=float)


def reference_method(df: pd.DataFrame) -> str | None:
    """The reference of the rows of one job: contact ``pdas``; Poisson the fastest direct backend."""
    if df.empty:
        return None
    problem = str(df["problem"].iloc[0])
    ok = df[df.get("converged", pd.Series(False, index=df.index)).fillna(False).astype(bool)]
    if REFERENCE.get(problem) != "fastest-direct":
        ref = REFERENCE.get(problem)
        return ref if ref in set(ok["method"]) else None
    direct = ok[ok["method"].isin(DIRECT)]
    if direct.empty or "seconds" not in direct:
        return None
    return str(direct.loc[direct["seconds"].astype(float).idxmin(), "method"])


def add_ratios(df: pd.DataFrame) -> pd.DataFrame:
    """Add ``reference`` and ``ratio`` (seconds / the reference's seconds of the same job and problem)."""
    df = df.reset_index(drop=True)
    df["reference"] = ""
    df["ratio"] = math.nan
    if "cpu_seconds" in df:
        df["cpu_ratio"] = math.nan
    for _, rows in df.groupby(["problem", "refine"], sort=False):
        ref = reference_method(rows)
        if ref is None:
            continue
        t_ref = float(rows.loc[rows["method"] == ref, "seconds"].iloc[0])
        df.loc[rows.index, "reference"] = ref
        df.loc[rows.index, "ratio"] = rows["seconds"].astype(float) / t_ref
        if "cpu_seconds" in rows:
            c_ref = float(rows.loc[rows["method"] == ref, "cpu_seconds"].iloc[0])
            df.loc[rows.index, "cpu_ratio"] = rows["cpu_seconds"].astype(float) / c_ref
    return df


def unstructured_table(df: pd.DataFrame) -> pd.DataFrame:
    """One row per (problem, refine, method): sizes, times, ratio, iterations, cond, memory, and the
    relative 2-norm difference to the reference peer's solution (``error``)."""
    df = add_ratios(df)
    columns = ["problem", "refine", "ndof", "n_sub", "method", "seconds", "ratio", "cpu_seconds", "cpu_ratio",
               "reference", "setup_seconds",
               "solve_seconds", "partition_seconds", "iterations", "cond", "peak_mb", "added_mb", "converged",
               "error", "load"]
    columns = [c for c in columns if c in df]
    return df.sort_values(["problem", "ndof", "method"])[columns].reset_index(drop=True)


def fits(df: pd.DataFrame, *, column: str = "seconds") -> dict[tuple[str, str], ExponentFit]:
    """Fitted exponent of ``column`` against ndof per (problem, method) (converged runs, >= 2 sizes)."""
    out = {}
    ok = df[df["converged"].fillna(False).astype(bool)] if "converged" in df else df
    for (problem, method), rows in ok.groupby(["problem", "method"], sort=False):
        try:
            out[(str(problem), str(method))] = fit_exponent(rows["ndof"], rows[column])
        except ValueError:
            continue
    return out


def unstructured_summary(df: pd.DataFrame, targets: Mapping[str, float] | None = None) -> dict[str, Any]:
    """Table, exponent fits and the targets (each with its measured value and whether it is met).

    ``targets`` (all optional): ``poisson_max_ratio`` (FETI-DP and BDDC over the
    fastest direct method at the largest size), ``contact_max_ratio`` (active
    set over pdas at the largest size), ``max_exponent`` (of every DD method),
    ``min_ndof``/``min_subdomains`` (of the largest case, for the targets to apply).
    """
    targets = dict(targets or {})
    table = unstructured_table(df)
    fitted = fits(df)
    checks = []
    for problem, key, methods in (("poisson", "poisson_max_ratio", DD_METHODS["poisson"]),
                                  ("contact", "contact_max_ratio", ("active-set",))):
        rows = table[table["problem"] == problem]
        if key not in targets or rows.empty:
            continue
        largest = rows[rows["ndof"] == rows["ndof"].max()]
        for method in methods:
            got = largest.loc[largest["method"] == method, "ratio"]
            value = float(got.iloc[0]) if len(got) else math.nan
            checks.append({"target": f"{problem} {method}: time / {largest['reference'].iloc[0] or 'reference'}"
                                     f" at {int(largest['ndof'].iloc[0]):,} dofs, {int(largest['n_sub'].iloc[0]):,}"
                                     f" subdomains", "limit": f"<= {targets[key]:g}",
                           "value": value, "met": bool(value <= targets[key])})
    if "max_exponent" in targets:
        for (problem, method), fit in fitted.items():
            if method in DD_METHODS.get(problem, ()):
                # a verdict needs a growth law: MIN_FIT_POINTS sizes and a time that grows (two tiny cases
                # fit exactly, R^2 = 1, and read "met" at p = -0.17; a review)
                law = fit.n_points >= MIN_FIT_POINTS and fit.exponent > 0
                note = "" if law else (f" (not a growth law: {fit.n_points} sizes)" if fit.n_points < MIN_FIT_POINTS
                                       else " (not a growth law: the time falls; sizes too small)")
                checks.append({"target": f"{problem} {method}: time ~ dofs^p", "limit": f"p <= {targets['max_exponent']:g}",
                               "value": fit.exponent, "note": note,
                               "met": bool(fit.exponent <= targets["max_exponent"]) if law else None})
    return {"table": table, "fits": fitted, "checks": checks}


def summary_markdown(summary: Mapping[str, Any], *, title: str = "Unstructured meshes: DD against direct solvers") -> str:
    """The summary as markdown: the table, the fitted exponents and the targets."""
    table: pd.DataFrame = summary["table"]
    lines = [f"# {title}", "", "Wall times in seconds (DD: METIS partition + substructuring + setup + solve; "
             "direct: factorization + solve of the assembled matrix); ratio to the reference of the same job; "
             "cpu_seconds/cpu_ratio: CPU time of the method's own call (DD without partition and "
             "substructuring) and its ratio; error: relative 2-norm difference to the reference peer's solution; "
             "load: 1-minute load average at the start of the run.", "",
             f"{NOTE_MARK} {only_sentence(DEFAULT)}", ""]
    shown = table.copy()
    for col in ("seconds", "cpu_seconds", "setup_seconds", "solve_seconds", "partition_seconds"):
        if col in shown:
            shown[col] = shown[col].map(lambda v: f"{v:.3g}" if pd.notna(v) else "")
    for col in ("ratio", "cpu_ratio", "load"):
        if col in shown:
            shown[col] = shown[col].map(lambda v: f"{v:.2f}" if pd.notna(v) else "")
    if "cond" in shown:
        shown["cond"] = shown["cond"].map(lambda v: f"{v:.1f}" if pd.notna(v) else "")
    if "error" in shown:
        shown["error"] = shown["error"].map(lambda v: f"{v:.1e}" if pd.notna(v) else "")
    for col in ("peak_mb", "added_mb"):
        if col in shown:
            shown[col] = shown[col].map(lambda v: f"{v:.0f}" if pd.notna(v) else "")
    lines.append(shown.to_markdown(index=False))
    lines += ["", "## Fitted exponents (time ~ c dofs^p)", "", "| problem | method | p | R^2 | points |",
              "|---|---|---|---|---|"]
    for (problem, method), fit in summary["fits"].items():
        lines.append(f"| {problem} | {method} | {fit.exponent:.2f} | {r2_text(fit.r2, fit.n_points)} | {fit.n_points} |")
    if summary["checks"]:
        lines += ["", "## Targets", "", "| target | limit | measured | met |", "|---|---|---|---|"]
        for c in summary["checks"]:
            met = "n/a" if c["met"] is None else ("yes" if c["met"] else "no")
            lines.append(f"| {c['target']} | {c['limit']} | {c['value']:.3g}{c.get('note', '')} | {met} |")
    return "\n".join(lines) + "\n"


_STYLES = {"fetidp": ("tab:blue", "o", "-"), "bddc": ("tab:cyan", "s", "-"), "active-set": ("tab:blue", "o", "-"),
           "smalbe": ("tab:purple", "^", "-"), "pdas": ("tab:red", "D", "--"),
           "sparsecholesky": ("tab:orange", "v", "--"), "pardiso": ("tab:red", "D", "--"),
           "mkl-pardiso": ("tab:brown", "P", "--"), "superlu": ("tab:pink", "<", "--"),
           "pyamg": ("tab:green", "x", ":")}


def plot_unstructured(df: pd.DataFrame, path: str | os.PathLike | None):
    """Wall time against dofs (log-log), one panel per problem, one line per method with its exponent."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    problems = [p for p in ("poisson", "contact") if p in set(df["problem"])] or ["poisson"]
    fig, axes = plt.subplots(1, len(problems), figsize=(6.5 * len(problems), 5), squeeze=False)
    fitted = fits(df)
    for ax, problem in zip(axes[0], problems):
        sub = df[df["problem"] == problem]
        for method, rows in sub.groupby("method", sort=False):
            rows = rows[rows["converged"].fillna(False).astype(bool)].sort_values("ndof")
            if rows.empty:
                continue
            color, marker, style = _STYLES.get(str(method), ("tab:gray", "x", ":"))
            fit = fitted.get((problem, str(method)))
            label = str(method) + (f", dofs^{fit.exponent:.2f}" if fit is not None else "")
            ax.plot(rows["ndof"], rows["seconds"], marker=marker, linestyle=style, color=color, label=label)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("degrees of freedom")
        ax.set_ylabel("wall time [s] (from the assembled problem)")
        ax.set_title(f"{problem}, unstructured P1, METIS subdomains")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    _save(fig, path)
    return fig
