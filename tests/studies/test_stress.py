"""Numerical stability stress tests (ddstudies.stress), the smaller "quick" tier.

Every case of ``catalog("quick")`` runs once (about 10 s) and must PASS its stated
criterion; the few cases that document known weaknesses (reported in
``reports/stress/stress.md`` by the full study) must still run cleanly (no crash, no
hang, no silent NaN) and are marked xfail when they FAIL. Targeted tests cover the
exposed true residual, the rejection of unattainable tolerances, the body
checkerboard, the one-line input errors and the Snakemake wiring of the study.
All loads are deterministic (seeded or closed-form).
"""
from __future__ import annotations

import math
import re
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from ddsolve import ProblemSpec, solve
from ddsolve.api import build_scene
from ddsolve.cli import main
from ddsolve.errors import InputError
from ddstudies import stress
from ddstudies.stress import StressCase, catalog, contact_load, evaluate, render_markdown, run_case

QUICK = catalog("quick")

#: Known weaknesses (FAIL in the study report): case name pattern -> why.
KNOWN = {
}


def known_issue(name: str) -> str | None:
    return next((why for pattern, why in KNOWN.items() if re.search(pattern, name)), None)


@pytest.fixture(scope="module")
def rows() -> dict[str, dict]:
    t0 = time.perf_counter()
    out = evaluate([run_case(case, timeout=60) for case in QUICK])
    seconds = time.perf_counter() - t0
    if seconds > 45:    # a note, not a failure: on a loaded machine the tier takes longer (a timed assert failed
        # every case of this module at a load average of 4 on 2 cores); CI's total time is what is budgeted
        warnings.warn(f"the quick stress tier took {seconds:.0f} s (expected under 45 s on an idle machine)")
    return {row["name"]: row for row in out}


@pytest.mark.slow
@pytest.mark.parametrize("name", [case.name for case in QUICK])
def test_stress_case(rows, name):
    row = rows[name]
    # whatever the criterion: no crash, no hang, no NaN behind a converged=True
    assert row["status"] not in ("crash", "timeout"), row["error"]
    assert not (row["nonfinite"] and row["converged"]), row["nonfinite"]
    if row["outcome"] == "FAIL" and known_issue(name):
        pytest.xfail(f"{known_issue(name)}: {row['note']}")
    assert row["outcome"] == "PASS", f"{row['claim']}: {row['note']}"


def test_catalog_shape():
    names = [case.name for case in QUICK]
    assert len(names) == len(set(names))
    assert {case.group for case in QUICK} == set(stress.GROUPS)
    assert all(case.criterion in stress.CRITERIA for case in QUICK)
    assert all(case.claim and "\n" not in case.claim for case in QUICK)
    by_name = {case.name: case for case in QUICK}
    for case in QUICK:                                  # baselines exist and run in the same job
        if case.baseline:
            assert by_name[case.baseline].series == case.series
    study = catalog("study")
    assert [c.name.split("_")[0] for c in study].count("jumps") == 7 * (3 * 2 + 2 * 2 * 2)
    assert max(c.spec.get("subdomains", 0) for c in study) == 32
    assert max(c.spec.get("elements", 0) for c in study) == 256
    assert max(c.spec.get("bodies", 0) for c in study) == 8
    with pytest.raises(InputError, match="tier"):
        catalog("huge")


def test_rho_scaling_keeps_iterations_multiplicity_does_not(rows):
    """The headline of the jump study, stated directly on the quick rows."""
    for meth in ("fetidp", "bddc", "feti", "feti-feti"):
        base = rows[f"jumps_{meth}_cb_rho_1"]["iterations"]
        for value in ("1e-06", "1e+06"):
            assert rows[f"jumps_{meth}_cb_rho_{value}"]["iterations"] <= 1.5 * base
            assert rows[f"jumps_{meth}_cb_multiplicity_{value}"]["iterations"] > 2 * base


# --------------------------------------------------------------------------- true residual
@pytest.mark.parametrize("fields", [
    {"method": "fetidp", "subdomains": 3, "elements": 4, "f": "random:1", "rho": "checkerboard:100"},
    {"method": "feti", "subdomains": 3, "elements": 4, "f": "random:1"},
    {"problem": "multibody", "method": "hybrid", "bodies": 3, "subdomains": 2, "elements": 2},
    {"problem": "multibody", "method": "feti-feti", "bodies": 3, "subdomains": 2, "elements": 2},
])
def test_true_residual_exposed(fields):
    res = solve(ProblemSpec.from_mapping({**fields, "rtol": 1e-10}))
    assert res.converged
    assert res.to_dict()["true_residual"] == pytest.approx(res.true_residual)
    r0, rec = res.residuals[0], res.residuals[-1]
    assert math.isfinite(res.true_residual)
    assert res.true_residual <= 10 * max(rec, 1e-10 * r0)
    assert res.true_residual == pytest.approx(rec, rel=1e-2, abs=1e-3 * 1e-10 * r0)


def test_true_residual_none_for_direct_and_contact():
    assert solve(ProblemSpec(method="direct", subdomains=2, elements=2)).to_dict()["true_residual"] is None
    res = solve(ProblemSpec(problem="contact", method="smalbe", subdomains=2, elements=2))
    assert res.true_residual is None and "true_residual" in res.to_dict()


def test_unattainable_tolerance_is_not_convergence():
    """rtol below round-off: the recursive PCG residual 'converges', the recomputed one cannot."""
    res = solve(ProblemSpec(method="bddc", subdomains=3, elements=4, f="random:0", rtol=1e-20, maxiter=200))
    assert not res.converged
    assert res.reason.startswith("tolerance not attained") and "\n" not in res.reason
    assert res.residuals[-1] <= 1e-20 * res.residuals[0] < res.true_residual
    ok = solve(ProblemSpec(method="bddc", subdomains=3, elements=4, f="random:0", rtol=1e-12))
    assert ok.converged and ok.reason.startswith("converged")


# --------------------------------------------------------------------------- body checkerboard
def test_body_checkerboard():
    spec = ProblemSpec.from_mapping({"problem": "multibody", "bodies": 3, "subdomains": 2, "elements": 2,
                                     "rho": "body-checkerboard:1e3"})
    scene = build_scene(spec)
    body = scene.subdomain_body
    for b in range(9):
        vals = np.unique(scene.rho[body == b])
        assert vals.size == 1
        bx, by = b % 3, b // 3
        assert vals[0] == (1e3 if (bx + by) % 2 else 1.0)
    contact = build_scene(ProblemSpec(problem="contact", subdomains=2, elements=2, rho="body-checkerboard:7"))
    assert np.all(contact.rho[contact.subdomain_body == 0] == 1.0)
    assert np.all(contact.rho[contact.subdomain_body == 1] == 7.0)
    with pytest.raises(InputError, match="body-checkerboard needs a value"):
        ProblemSpec.from_mapping({"rho": "body-checkerboard"})
    with pytest.raises(InputError, match="rho"):
        ProblemSpec.from_mapping({"rho": "body-checkerboard:-1"})


# --------------------------------------------------------------------------- one-line errors
@pytest.mark.parametrize("argv, field, text", [
    (["--problem", "contact", "--f", "1"], "f", "negative integral"),
    (["--problem", "contact", "--f", "0", "--method", "smalbe"], "f", "negative integral"),
    (["--subdomains", "1", "--elements", "4"], "subdomains", "at least 2 subdomains"),
    (["--problem", "multibody", "--bodies", "3", "--subdomains", "1", "--elements", "2"], "subdomains", "floats"),
    (["--problem", "multibody", "--bodies", "3", "--subdomains", "1", "--elements", "2", "--method", "hybrid"],
     "subdomains", "floats"),
    (["--problem", "contact", "--subdomains", "1", "--elements", "4"], "subdomains", "floats"),
])
def test_one_line_input_errors(capsys, argv, field, text):
    assert main(["solve", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"ddsolve: error: {field}: ") and text in err


def test_one_subdomain_direct_still_works():
    for fields in ({"problem": "multibody", "method": "direct", "bodies": 3, "subdomains": 1, "elements": 2},
                   {"problem": "contact", "method": "direct", "subdomains": 1, "elements": 4}):
        assert solve(ProblemSpec.from_mapping(fields)).converged


# --------------------------------------------------------------------------- contact loads
def test_contact_loads():
    n, m = 2, 4
    area = (1.0 / (n * m)) ** 2
    half = (n * m) ** 2                     # elements of Omega^1 come first
    for name, sign in (("full", -1), ("single-node", -1), ("barely:1e-8", -1)):
        f = contact_load(name, n, m)
        assert f.shape == (2 * half,) and np.all(np.isfinite(f))
        assert np.sign(f[half:].sum()) == sign
    assert f[half:].sum() * area == pytest.approx(-1e-8, rel=1e-6)
    assert contact_load("unloaded", n, m)[half:].sum() == 0.0
    single = contact_load("single-node", n, m)[:half]
    assert np.count_nonzero(single) == 2 and single.sum() * area == pytest.approx(30.0)
    with pytest.raises(InputError, match="even"):
        contact_load("single-node", 1, 3)
    with pytest.raises(InputError, match="load"):
        contact_load("sideways", n, m)


# --------------------------------------------------------------------------- runner and report
def test_runner_never_raises(monkeypatch):
    case = StressCase("t_crash", "degenerate", "t", "a crash is recorded", "accurate",
                      {"method": "fetidp", "subdomains": 2, "elements": 2})

    def boom(spec):
        raise RuntimeError("kaboom\nsecond line")

    monkeypatch.setattr("ddsolve.api.solve", boom)
    rec = run_case(case)
    assert rec["status"] == "crash" and rec["error"] == "RuntimeError: kaboom"
    assert evaluate([rec])[0]["outcome"] == "FAIL"

    monkeypatch.setattr("ddsolve.api.solve", lambda spec: time.sleep(5))
    t0 = time.perf_counter()
    rec = run_case(case, timeout=0.3)
    assert rec["status"] == "timeout" and time.perf_counter() - t0 < 3
    assert evaluate([rec])[0]["note"].startswith("timeout")

    bad = StressCase("t_input", "degenerate", "t", "bad input", "input_error", {"method": "nope"},
                     expect_message="method:")
    assert evaluate([run_case(bad)])[0]["outcome"] == "PASS"


def test_silent_nan_fails():
    case = StressCase("t_nan", "degenerate", "t", "NaN", "not_converged",
                      {"method": "fetidp", "subdomains": 2, "elements": 2})
    rec = {**run_case(case), "status": "ok", "converged": True, "nonfinite": ["u"], "reason": "converged"}
    row = evaluate([rec])[0]
    assert row["outcome"] == "FAIL" and "non-finite" in row["note"]


def test_report_one_row_per_case(rows):
    md = render_markdown(list(rows.values()))
    table_rows = [line for line in md.splitlines() if line.startswith("| `")]
    assert len(table_rows) == len(rows)
    for line in table_rows:
        assert line.count(" | ") == 9 and ("**PASS**" in line or "**FAIL**" in line)
    assert f"{len(rows)} cases" in md
    assert "Rule sets: every number here is from rule set 'default'" in md      # the rules named (a review)


# --------------------------------------------------------------------------- Snakemake wiring
def _snakemake(wd: Path, *args: str) -> str:
    from conftest import run_snakemake

    proc = run_snakemake(wd, *args)
    return proc.stdout + proc.stderr


def test_stress_study_dry_run(tmp_path):
    from conftest import copy_workflow

    pytest.importorskip("snakemake")
    copy_workflow(tmp_path)
    out = _snakemake(tmp_path, "-n", "--cores", "1", "--configfile", "config/stress.yaml",
                     "--config", "study=stress_quick", "tier=quick")
    n_jobs = len({case.group for case in QUICK})  # the quick tier runs one job per group
    assert re.search(rf"^stress_series\s+{n_jobs}\s*$", out, flags=re.MULTILINE), out
    assert re.search(r"^stress_report\s+1\s*$", out, flags=re.MULTILINE), out
    assert "solve_case" not in out
    out = _snakemake(tmp_path, "-n", "--cores", "1", "--configfile", "config/poisson.yaml")
    assert "stress_series" not in out and "stress_report" not in out


def test_notes_are_cut_at_a_word():
    """The report's notes ended mid-word ("... to the tolerance: esti"; a review, 2026-11-28)."""
    from ddstudies.stress.criteria import _short
    text = "converged: the residual reached the tolerance: estimated error 1e-3"
    assert _short(text, 40) == "converged: the residual reached the..."
    assert _short(text, len(text)) == text and len(_short(text, 50)) <= 50
