"""An alpha-beta model of the time per iteration of distributed FETI-DP (a model, not a measurement).

    t_iter(P) = t_comp(P) + alpha * m(P) + beta * b(P) + t_coarse(P) + n_ar * log2(P) * alpha

* t_comp(P): measured compute time per iteration of one subdomain (from a run
  with P = 1), times the subdomains per rank (weak: fixed; strong: N / P);
* m(P), b(P): messages and bytes one rank sends per iteration: 2 neighbour
  exchanges (F and the preconditioner) with up to 8 neighbours in a 2-D box
  partition of the subdomains, one double per multiplier on the shared side of
  the rank's box (sqrt(n_loc) subdomain sides of H/h - 1 dual nodes);
* t_coarse(P): the redundant coarse solve (forward and backward substitution
  with a nested-dissection factor of the 2-D coarse grid, nnz(L) ~
  c_fill n_c log2 n_c, at ``flops`` per second) plus the bandwidth of the
  Allreduce of its right-hand side (2 n_c doubles); n_c = one primal dof per
  interior cross point ~ N;
* n_ar Allreduces of latency log2(P) alpha (3 of PCG, 1 coarse).

Parallel efficiency: weak E = t_iter(1) / t_iter(P); strong E = t_iter(1) / (P t_iter(P)).
Run ``python -m ddsolve.parallel.model P1.json P2.json`` with the JSON of
``mpiexec -n 1`` and ``mpiexec -n 2`` solves to calibrate on P = 1, compare
with P = 2 and print the projections (docs/parallel.md; the study of
config/mpi.yaml does the same).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass

__all__ = ["measured_report", "Machine", "Calibration", "calibrate", "t_iter", "projection", "mpi_report", "main"]


@dataclass(frozen=True)
class Machine:
    """Assumed network and coarse-solve rates."""

    alpha: float = 1e-6            # latency per message, s
    beta: float = 1.0 / 10e9       # s per byte (10 GB/s)
    flops: float = 1e9             # sparse triangular solves (memory bound), flop/s
    c_fill: float = 8.0            # nnz(L) ~ c_fill n log2 n for nested dissection in 2-D
    allreduces: int = 4            # per iteration: 3 of PCG, 1 coarse right-hand side


@dataclass(frozen=True)
class Calibration:
    """Measured inputs: the per-subdomain compute time per iteration and the subdomain size."""

    t_sub: float                   # s per iteration per subdomain (compute only)
    elements: int                  # H/h


def _box_side(n_loc: float) -> float:
    return math.sqrt(max(n_loc, 1.0))


def messages_bytes(P: int, n_loc: float, elements: int) -> tuple[float, float]:
    """Messages and bytes one rank sends per iteration (2-D box partition; strips for P = 2)."""
    if P == 1:
        return 0.0, 0.0
    if P == 2:                                   # two strips: one neighbour, one shared side of sqrt(2 n_loc)
        side = math.sqrt(2 * n_loc) * (elements - 1)
        return 2.0, 2 * 8.0 * side
    side = _box_side(n_loc) * (elements - 1)     # dual nodes on one side of the rank's box
    return 2 * 8.0, 2 * (4 * 8.0 * side + 4 * 8.0)


def coarse_seconds(n_c: float, P: int, m: Machine) -> float:
    """Redundant coarse solve plus the Allreduce bandwidth of its right-hand side, per iteration."""
    if n_c <= 1:
        return 0.0
    nnz = m.c_fill * n_c * math.log2(n_c)
    solve = 4.0 * nnz / m.flops                  # forward + backward, 2 flops per nonzero
    reduce = 0.0 if P == 1 else 2.0 * 8.0 * n_c * m.beta
    return solve + reduce


def t_iter(P: int, n_total: float, cal: Calibration, m: Machine) -> dict:
    """Modelled seconds per iteration with P ranks and n_total subdomains (and its parts)."""
    n_loc = n_total / P
    comp = cal.t_sub * n_loc
    msgs, nbytes = messages_bytes(P, n_loc, cal.elements)
    comm = m.alpha * msgs + m.beta * nbytes
    coarse = coarse_seconds(n_total, P, m)
    reduce = m.allreduces * math.log2(P) * m.alpha if P > 1 else 0.0
    return {"P": P, "subdomains": n_total, "t_comp": comp, "t_p2p": comm, "t_coarse": coarse,
            "t_allreduce": reduce, "t_iter": comp + comm + coarse + reduce}


def projection(cal: Calibration, m: Machine, n_per_rank: float, n_strong: float,
               ranks=(1, 2, 16, 128, 1000, 10000)) -> list[dict]:
    """Weak (n_per_rank subdomains per rank) and strong (n_strong subdomains) rows with efficiencies."""
    rows = []
    weak1 = t_iter(1, n_per_rank, cal, m)["t_iter"]
    strong1 = t_iter(1, n_strong, cal, m)["t_iter"]
    for P in ranks:
        w = t_iter(P, n_per_rank * P, cal, m)
        rows.append({"scaling": "weak", **w, "efficiency": weak1 / w["t_iter"]})
    for P in ranks:
        if n_strong < P:
            continue
        s = t_iter(P, n_strong, cal, m)
        rows.append({"scaling": "strong", **s, "efficiency": strong1 / (P * s["t_iter"])})
    return rows


def calibrate(run: dict, m: Machine) -> Calibration:
    """The per-subdomain compute time per iteration of a P = 1 run's JSON (its modelled coarse solve removed)."""
    n_sub = run["bodies"] ** 2 * run["subdomains"] ** 2
    t1 = run["comm"]["krylov_seconds"] / max(run["iterations"], 1)
    return Calibration(t_sub=max(t1 - coarse_seconds(n_sub, 1, m), 0.0) / n_sub, elements=run["elements"])


def _peer_seconds(run: dict, first: dict) -> float:
    """The P = 1 solve phase a run's speed-up is relative to: the peer measured in the run's own job,
    alternating with it (``"peer"``, written by the study's rule mpi_case), else the first run's."""
    return float(run.get("peer", {}).get("solve_seconds", first["solve_seconds"]))


def _serial_seconds(first: dict) -> float:
    """The serial solver's solve phase measured beside the P = 1 run (its own if none was)."""
    return float(first.get("serial", {}).get("solve_seconds", first["solve_seconds"]))


def _loads(values) -> str:
    return "/".join(f"{x:.2f}" for x in values)


def _serial_line(first: dict) -> str:
    """What "speed-up" (against the distributed code on 1 rank, in the row's job) and "vs serial" are relative to."""
    serial = first.get("serial")
    reference = ("Speed-up: against the distributed code on one rank measured in the same job as the row, the two "
                 "runs alternating (column \"P = 1 in the job s\"; the P = 1 row is its own reference)")
    if not serial:
        return reference + "; no serial run recorded.\n"
    return (f"{reference}. vs serial: against the serial solver without mpiexec, measured in the P = 1 job "
            f"({serial['solve_seconds']:.3f} s, {serial['iterations']} iterations, load average "
            f"{_loads(serial['load_average'])}).\n"
            "Setup s: scene, topology, assembly, factorizations and the explicit local blocks (the maximum over "
            "ranks); solve s: from the right-hand side to the solution; MPI s per rank: each rank's time inside "
            "MPI calls during the method (transfers and waiting: the spread is the load imbalance); peak RSS MB "
            "per rank: each rank's peak resident memory (rank 0 also holds the input mesh and topology at "
            "setup).\n")


def _measured_row(run: dict, first: dict) -> dict:
    """The measured columns of one run's row (speed-up against :func:`_peer_seconds`, "vs serial" against the
    serial run beside the first run)."""
    comm = run["comm"]
    return {"ranks": run["n_ranks"], "ndof": run["ndof"], "iterations": run["iterations"],
            "solve_seconds": run["solve_seconds"],
            "peer_solve_seconds": _peer_seconds(run, first),
            "speedup_solve": _peer_seconds(run, first) / run["solve_seconds"],
            "speedup_vs_serial": _serial_seconds(first) / run["solve_seconds"],
            "messages_per_iteration": comm["messages_per_iteration"],
            "bytes_per_iteration": comm["bytes_per_iteration"],
            "allreduces_per_iteration": comm["allreduces_per_iteration"],
            "coarse_seconds": comm["coarse_seconds"],
            "setup_seconds": run["setup_seconds"],
            # per rank, the time inside MPI calls in the solve: the spread is the load imbalance
            "mpi_seconds": "/".join(f"{x:.3f}" for x in comm.get("mpi_seconds", [])) or "-",
            # peak resident memory of each rank (rank 0 also holds the input mesh and topology at setup)
            "peak_rss_mb": "/".join(f"{x:.0f}" for x in run.get("peak_rss_mb_per_rank", [])) or "-",
            "load_average": _loads(run.get("load_average", []))}


def mpi_report(runs: list[dict], m: Machine = Machine(), strong_subdomains: float = 40000.0) -> tuple[list[dict], str]:
    """Rows (one per run: measured and modelled) and a markdown report; the first run (P = 1) calibrates."""
    first = runs[0]
    cal = calibrate(first, m)
    n_sub = first["bodies"] ** 2 * first["subdomains"] ** 2
    rows = []
    for run in runs:
        row = _measured_row(run, first)
        row["krylov_seconds"] = run["comm"]["krylov_seconds"]
        row["t_iter_measured"] = run["comm"]["krylov_seconds"] / max(run["iterations"], 1)
        row["t_iter_model"] = t_iter(run["n_ranks"], n_sub, cal, m)["t_iter"]
        rows.append(row)
    lines = ["# Distributed solve (ddsolve.parallel)", "",
             f"{first['method']}, {first['ndof']} dofs, {n_sub} subdomains, H/h = {first['elements']}; "
             f"rule set {first.get('preset') or 'default'!r} (ddsolve.presets) in every run.", "",
             _serial_line(first),
             "| P | iterations | solve s | P = 1 in the job s | speed-up | vs serial | s/iteration (measured) "
             "| s/iteration (model) "
             "| messages/it | bytes/it | allreduces/it | MPI s per rank | setup s | peak RSS MB per rank "
             "| load average (before/after) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['ranks']} | {r['iterations']} | {r['solve_seconds']:.3f} | {r['peer_solve_seconds']:.3f} "
                     f"| {r['speedup_solve']:.2f} "
                     f"| {r['speedup_vs_serial']:.2f} | {r['t_iter_measured']:.4f} | {r['t_iter_model']:.4f} | {r['messages_per_iteration']:g} "
                     f"| {r['bytes_per_iteration']:g} | {r['allreduces_per_iteration']:g} | {r['mpi_seconds']} "
                     f"| {r['setup_seconds']:.2f} | {r['peak_rss_mb']} | {r['load_average']} |")
    lines += ["", "## Alpha-beta model (a model, not a measurement)", "",
              f"alpha = {m.alpha:g} s, beta = {m.beta:g} s/byte, coarse solve at {m.flops:g} flop/s; "
              f"t_sub = {cal.t_sub:.3e} s per subdomain and iteration (measured, P = 1). "
              f"Weak: {n_sub} subdomains per rank; strong: {strong_subdomains:g} subdomains.", "",
              "| scaling | P | t_comp | t_p2p | t_coarse | t_allreduce | t_iter | efficiency |",
              "|---|---|---|---|---|---|---|---|"]
    for p in projection(cal, m, n_per_rank=n_sub, n_strong=strong_subdomains):
        lines.append(f"| {p['scaling']} | {p['P']} | {p['t_comp']:.3e} | {p['t_p2p']:.3e} | {p['t_coarse']:.3e} "
                     f"| {p['t_allreduce']:.3e} | {p['t_iter']:.3e} | {p['efficiency']:.3f} |")
    return rows, "\n".join(lines) + "\n"


def measured_report(runs: list[dict]) -> tuple[list[dict], str]:
    """Rows and a markdown table of measured solve phases only (no model), the first run the reference.

    For methods the alpha-beta model does not cover (the active set method of
    ``--problem contact``: face PCR, PCG on (5.4) and MPRGP, four to six times the
    synchronisations of FETI-DP per iteration).
    """
    first = runs[0]
    rows = [{"problem": run["problem"], "method": run["method"], **_measured_row(run, first),
             "t_iter_measured": run["solve_seconds"] / max(run["iterations"], 1)} for run in runs]
    lines = [f"{first['problem']} / {first['method']}, {first['ndof']} dofs, {first['subdomains']} x "
             f"{first['subdomains']} subdomains per body, H/h = {first['elements']} (measured only); "
             f"rule set {first.get('preset') or 'default'!r} (ddsolve.presets) in every run.", "",
             _serial_line(first),
             "| P | iterations | solve s | P = 1 in the job s | speed-up | vs serial | solve s/iteration | messages/it "
             "| bytes/it "
             "| allreduces/it | MPI s per rank | setup s | peak RSS MB per rank | load average (before/after) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['ranks']} | {r['iterations']} | {r['solve_seconds']:.3f} | {r['peer_solve_seconds']:.3f} "
                     f"| {r['speedup_solve']:.2f} "
                     f"| {r['speedup_vs_serial']:.2f} | {r['t_iter_measured']:.4f} | {r['messages_per_iteration']:.1f} "
                     f"| {r['bytes_per_iteration']:.0f} | {r['allreduces_per_iteration']:.1f} | {r['mpi_seconds']} "
                     f"| {r['setup_seconds']:.2f} | {r['peak_rss_mb']} | {r['load_average']} |")
    return rows, "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """``python -m ddsolve.parallel.model P1.json [P2.json ...]``: print the report of :func:`mpi_report`."""
    parser = argparse.ArgumentParser(prog="python -m ddsolve.parallel.model",
                                     description="alpha-beta model of distributed FETI-DP (docs/parallel.md)")
    parser.add_argument("runs", nargs="+", help="JSON of mpiexec -n P ddsolve solve --json; the first with P = 1")
    parser.add_argument("--strong-subdomains", type=float, default=40000.0)
    args = parser.parse_args(argv)
    runs = [json.load(open(path)) for path in args.runs]
    _, text = mpi_report(runs, strong_subdomains=args.strong_subdomains)
    print(text)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
