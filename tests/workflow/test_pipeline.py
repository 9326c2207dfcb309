"""The Snakemake pipeline, run on a copy of the workflow in a temporary directory.

The dry runs need only Snakemake; the real run of a tiny Poisson study
(config/poisson.yaml on a 2 x 2 grid) needs the solvers (``ddsolve.api``) and is skipped without them.
"""
from __future__ import annotations


import pandas as pd
import pytest
from conftest import copy_workflow, planned
from conftest import run_snakemake as snakemake

pytest.importorskip("snakemake")


#: A tiny Poisson study: config/poisson.yaml with these keys replaced.
TINY = "study: quick\nsubdomains: [2]\nelements: [2, 4]\n"


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A copy of Snakefile, workflows/ and config/ (outputs never touch the repository)."""
    wd = copy_workflow(tmp_path_factory.mktemp("pipeline"))
    (wd / "tiny.yaml").write_text(TINY)
    return wd


def test_dry_run_poisson_study(workdir):
    poisson = planned(snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/poisson.yaml"))
    assert poisson == {"solve_case": 3 * 3 * 4, "aggregate": 1, "table": 1, "plot_cond": 1, "table_4": 0,
                       "figure_4": 0, "all": 1}
    tiny = planned(snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/poisson.yaml", "tiny.yaml"))
    assert tiny == {"solve_case": 6, "aggregate": 1, "table": 1, "plot_cond": 1, "table_4": 0,
                    "figure_4": 0, "all": 1}


def test_bad_config_is_rejected(workdir):
    (workdir / "bad.yaml").write_text("kind: grid\nstudy: bad\nmethods: [feti, newton]\nsubdomains: [2]\nelements: [2]\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "bad.yaml", check=False)
    assert proc.returncode != 0
    assert "invalid config (config.schema.yaml): methods/1: 'newton' is not one of" in proc.stdout + proc.stderr


@pytest.mark.slow
def test_quick_study_end_to_end(workdir):
    snakemake(workdir, "--cores", "2", "--configfile", "config/poisson.yaml", "tiny.yaml")
    results = workdir / "results" / "quick"
    reports = workdir / "reports" / "quick"
    for method in ("feti", "fetidp", "bddc"):
        for m in (2, 4):
            assert (results / method / f"Ns2_m{m}.h5").is_file()
            assert (workdir / "logs" / "quick" / method / f"Ns2_m{m}.log").is_file()
    df = pd.read_csv(results / "summary.csv")
    assert len(df) == 6 and set(df["method"]) == {"feti", "fetidp", "bddc"}
    assert df["converged"].all() and (df["cond"] >= 1 - 1e-8).all()
    table = (reports / "table.md").read_text()
    assert "FETI-DP cond" in table and "BDDC iter" in table
    assert "Rule sets: every number here is from rule set 'default'" in table     # named (a review)
    assert "\\begin{tabular}" in (reports / "table.tex").read_text()
    assert (reports / "cond_vs_Hh.png").read_bytes()[:4] == b"\x89PNG"
    assert not list(results.rglob("*.tmp"))
    # the full study's outputs are separate and untouched
    assert not (workdir / "results" / "poisson").exists()

    # finished cases are never rerun ...
    again = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/poisson.yaml", "tiny.yaml")
    assert "Nothing to be done" in again.stdout + again.stderr
    # ... a new H/h adds only its cases ...
    (workdir / "more.yaml").write_text("elements: [2, 4, 8]\n")
    more = planned(snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/poisson.yaml",
                             "tiny.yaml", "more.yaml"))
    assert more["solve_case"] == 3 and more["aggregate"] == 1
    # ... and a changed parameter reruns the cases it affects (params rerun-trigger)
    (workdir / "rtol.yaml").write_text("rtol: 1.0e-8\n")
    rerun = planned(snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/poisson.yaml",
                              "tiny.yaml", "rtol.yaml"))
    assert rerun["solve_case"] == 6
