"""The unstructured study (kind unstructured): schema, dry run, and a tiny run end to end."""
from __future__ import annotations

import re

import pandas as pd
import pytest
import yaml
from conftest import ROOT, copy_workflow
from conftest import run_snakemake as snakemake

from ddstudies.workflow import ConfigError, validate

pytest.importorskip("snakemake")

SCHEMA = ROOT / "workflows" / "schemas" / "unstructured.schema.yaml"


def config() -> dict:
    return yaml.safe_load((ROOT / "config" / "unstructured.yaml").read_text())


def test_config_reaches_a_million_dofs_and_a_thousand_subdomains():
    cfg = validate(config(), SCHEMA)
    poisson = cfg["problems"]["poisson"]
    assert max(poisson["refine"]) == 4 and max(poisson["parts"]) >= 1000 and poisson["maxh"] <= 0.017
    assert cfg["problems"]["contact"]["max_refine"] == {"smalbe": 2}


@pytest.mark.parametrize("change, where", [
    ({"problems": {"poisson": {"maxh": 0.1, "refine": [0], "parts": 4, "methods": ["cg"]}}}, "methods/0"),
    ({"problems": {"heat": {"maxh": 0.1, "refine": [0], "parts": 4, "methods": ["fetidp"]}}}, "heat"),
    ({"extra": 1}, "extra"),
    ({"cond_law": {"methods": ["fetidp"], "primals": ["edges"],
                   "fixed_P": {"maxh": 0.1, "refine": [0, 1], "parts": 4}}},
     r"cond_law/primals/0: 'edges' is not one of \['vertices', 'vertices\+edges'\]"),
    ({"cond_law": {"methods": ["feti"], "fixed_P": {"maxh": 0.1, "refine": [0, 1], "parts": 4}}},
     "cond_law/methods/0"),
    ({"cond_law": {"methods": ["fetidp"]}}, "cond_law"),
    ({"cond_law": {"methods": ["fetidp"], "fixed_P": {"maxh": 0, "refine": [0, 1], "parts": 4}}},
     "cond_law/fixed_P/maxh"),
    ({"cond_law": {"methods": ["fetidp"], "fixed_P": {"maxh": 0.1, "refine": [0], "parts": 4}}},
     "cond_law/fixed_P/refine"),
    ({"contact_figure": {"maxh": 0.1, "parts": 0}}, "contact_figure/parts"),
    ({"contact_figure": {"maxh": 0.1, "parts": 2, "method": "pdas"}}, "contact_figure/method"),
])
def test_schema_rejects(change, where):
    with pytest.raises(ConfigError, match=where):
        validate({**config(), **change}, SCHEMA)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return copy_workflow(tmp_path_factory.mktemp("unstructured"))


def test_dry_run_plans_one_job_per_problem_and_refinement(workdir):
    proc = snakemake(workdir, "-n", "--cores", "2", "--configfile", "config/unstructured.yaml")
    counts = {rule: int(n) for rule, n in re.findall(r"^(\w+)\s+(\d+)\s*$", proc.stdout + proc.stderr,
                                                      flags=re.MULTILINE)}
    assert counts["unstructured_case"] == 10 and counts["unstructured_summary"] == 1
    assert counts["unstructured_plot"] == 1
    # cond_law: fixed_Hh (5 points) and fixed_P (5 points) share (refine 1, P 16), x 2 methods x 2 primal sets
    assert counts["unstructured_cond_case"] == 2 * 2 * (5 + 5 - 1) and counts["unstructured_cond_aggregate"] == 1
    assert counts["unstructured_cond_law"] == 1 and counts["unstructured_contact_figure"] == 1


def test_mismatched_parts_are_refused(workdir):
    (workdir / "bad.yaml").write_text("problems: {poisson: {maxh: 0.1, refine: [0, 1], parts: [4], "
                                      "methods: [fetidp]}}\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/unstructured.yaml", "bad.yaml",
                     check=False)
    assert proc.returncode != 0 and "parts: 1 values for 2 refinements" in proc.stdout + proc.stderr


def test_cond_law_sweep_without_two_points_is_refused(workdir):
    (workdir / "bad_cond.yaml").write_text("cond_law: {fixed_Hh: {maxh: 0.1, refine: [0, 1], parts: 4}}\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/unstructured.yaml", "bad_cond.yaml",
                     check=False)
    assert proc.returncode != 0
    assert "invalid config: cond_law: fixed_Hh: needs at least 2 distinct parts" in proc.stdout + proc.stderr


@pytest.mark.slow
def test_tiny_study_runs(workdir):
    (workdir / "tiny.yaml").write_text(yaml.safe_dump({
        "kind": "unstructured", "study": "tiny_unstructured",
        "problems": {"poisson": {"maxh": 0.2, "refine": [0, 1], "parts": [2, 4],
                                 "methods": ["fetidp", "bddc", "superlu", "pyamg"]},
                     "contact": {"maxh": 0.25, "refine": [0], "parts": 2, "methods": ["active-set", "pdas"]}},
        "direct": "superlu", "targets": {"poisson_max_ratio": 0.5, "max_exponent": 1.1},
        "cond_law": {"methods": ["fetidp", "bddc"], "fixed_Hh": {"maxh": 0.25, "refine": [0, 1], "parts": [2, 8]},
                     "fixed_P": {"maxh": 0.25, "refine": [0, 1], "parts": 2}},
        "contact_figure": {"maxh": 0.25, "parts": 2}}))
    snakemake(workdir, "--cores", "1", "--configfile", "tiny.yaml")
    table = pd.read_csv(workdir / "reports" / "tiny_unstructured" / "unstructured.csv")
    assert set(table["method"]) == {"fetidp", "bddc", "superlu", "pyamg", "active-set", "pdas"}
    assert table["converged"].all()
    ref = table[table["method"] == table["reference"]]
    assert (ref["ratio"] == 1.0).all()
    text = (workdir / "reports" / "tiny_unstructured" / "unstructured.md").read_text()
    assert "## Targets" in text and "poisson fetidp" in text
    assert (workdir / "reports" / "tiny_unstructured" / "unstructured.png").stat().st_size > 0
    # the condition-number sweeps: one validated HDF5 per case, a manifest, the table with both sweeps
    cond = workdir / "results" / "tiny_unstructured" / "cond"
    assert len(list(cond.glob("*/*.h5"))) == 2 * 3 and (cond / "summary.sha256").exists()
    law = pd.read_csv(workdir / "reports" / "tiny_unstructured" / "cond_law.csv")
    assert set(law["sweep"]) == {"fixed_Hh", "fixed_P"} and law["converged"].all() and (law["cond"] >= 1).all()
    text = (workdir / "reports" / "tiny_unstructured" / "cond_law.md").read_text()
    assert "cond = a + b log P" in text and "1 + log(H/h)" in text
    for name in ("cond_law.png", "contact_solution.png"):
        assert (workdir / "reports" / "tiny_unstructured" / name).stat().st_size > 10_000
    # a truncated cond result: checked before planning like the grid studies' results (it needs this run's
    # outputs, so it is part of this test rather than a test of its own that skipped without them)
    victim = cond / "bddc" / "h0.25_r1_P8.h5"
    victim.write_bytes(victim.read_bytes()[:200])
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "tiny.yaml")
    text = proc.stdout + proc.stderr
    assert "corrupt result results/tiny_unstructured/cond/bddc/h0.25_r1_P8.h5" in text
    assert (cond / "bddc" / "h0.25_r1_P8.h5.corrupt").exists() and not victim.exists()
    counts = {rule: int(n) for rule, n in re.findall(r"^(\w+)\s+(\d+)\s*$", text, flags=re.MULTILINE)}
    assert counts["unstructured_cond_case"] == 1 and counts["unstructured_cond_aggregate"] == 1
    assert counts["unstructured_cond_law"] == 1 and "unstructured_case" not in counts
    # another direct backend reruns the contact job (its pdas faces factor with it), not the Poisson ones,
    # which do not read it (they reran on it before: every finished Poisson case)
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "tiny.yaml", "--config", "direct=mkl-pardiso")
    text = proc.stdout + proc.stderr
    counts = {rule: int(n) for rule, n in re.findall(r"^(\w+)\s+(\d+)\s*$", text, flags=re.MULTILINE)}
    assert counts["unstructured_case"] == 1 and "results/tiny_unstructured/contact/r0.csv" in text
