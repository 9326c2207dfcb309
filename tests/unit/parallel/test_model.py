"""The alpha-beta model of ddsolve.parallel.model (no MPI needed)."""
from __future__ import annotations

import math

import pytest

from ddsolve.parallel.model import Calibration, Machine, messages_bytes, projection, t_iter


def test_single_rank_has_no_communication():
    cal, m = Calibration(t_sub=1e-4, elements=64), Machine()
    row = t_iter(1, 256, cal, m)
    assert row["t_p2p"] == 0.0 and row["t_allreduce"] == 0.0
    assert row["t_comp"] == pytest.approx(256 * 1e-4)


def test_counts_and_terms():
    # P = 2 strips of 128 subdomains of H/h = 64: one cut of 16 sides x 63 dual nodes, 2 exchanges
    assert messages_bytes(2, 128, 64) == (2.0, 2 * 8.0 * 16 * 63)
    m = Machine()
    row = t_iter(2, 256, Calibration(t_sub=1e-4, elements=64), m)
    assert row["t_p2p"] == pytest.approx(2 * m.alpha + 2 * 8 * 16 * 63 * m.beta)
    assert row["t_allreduce"] == pytest.approx(4 * m.alpha)


def test_projection_efficiencies_fall_with_the_coarse_problem():
    rows = projection(Calibration(t_sub=1e-4, elements=64), Machine(), n_per_rank=256, n_strong=40000)
    weak = [r for r in rows if r["scaling"] == "weak"]
    strong = [r for r in rows if r["scaling"] == "strong"]
    assert weak[0]["efficiency"] == 1.0 and strong[0]["efficiency"] == 1.0
    assert all(a["efficiency"] >= b["efficiency"] for a, b in zip(weak, weak[1:]))
    big = weak[-1]
    assert big["P"] == 10000 and big["t_coarse"] > big["t_comp"]       # the coarse problem is the limit
    assert all(math.isfinite(r["t_iter"]) for r in rows)


def _run(P: int, solve: float, **extra) -> dict:
    """A study JSON (the keys the reports read) of a P-rank contact run."""
    return {"problem": "contact", "method": "active-set", "n_ranks": P, "ndof": 100, "subdomains": 2,
            "elements": 4, "iterations": 7, "solve_seconds": solve, "setup_seconds": 1.0,
            "comm": {"messages_per_iteration": 0.0, "bytes_per_iteration": 0.0, "allreduces_per_iteration": 1.0,
                     "coarse_seconds": 0.0}, **extra}


def test_speed_up_is_against_the_one_rank_run_of_the_same_job():
    """A P > 1 run with a "peer" (one rank, timed in its job) is compared with that peer, not with the
    P = 1 job's run; "vs serial" stays against the serial run of the P = 1 job; without a peer, the P = 1 run."""
    from ddsolve.parallel.model import measured_report

    first = _run(1, 2.0, serial={"solve_seconds": 2.2, "iterations": 7, "load_average": [0.1, 0.2]})
    rows, text = measured_report([first, _run(2, 1.0, peer={"solve_seconds": 1.8, "iterations": 7,
                                                             "load_average": [0.3, 0.3]}), _run(3, 0.8)])
    assert [r["speedup_solve"] for r in rows] == pytest.approx([1.0, 1.8, 2.5])
    assert [r["peer_solve_seconds"] for r in rows] == pytest.approx([2.0, 1.8, 2.0])
    assert [r["speedup_vs_serial"] for r in rows] == pytest.approx([1.1, 2.2, 2.75])
    assert "| 2 | 7 | 1.000 | 1.800 | 1.80 | 2.20 |" in text and "measured in the same job" in text
    assert "rule set 'default' (ddsolve.presets) in every run" in text             # the rules named
    _, thesis = measured_report([_run(1, 2.0, preset="thesis")])
    assert "rule set 'thesis' (ddsolve.presets) in every run" in thesis
