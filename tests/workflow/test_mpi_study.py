"""The MPI benchmark study (kind mpi, config/mpi.yaml): schema, dry run, and a tiny run under mpiexec."""
from __future__ import annotations

import json
import re
import shutil

import pandas as pd
import pytest
import yaml
from conftest import ROOT, copy_workflow
from conftest import run_snakemake as snakemake

from ddstudies.workflow import ConfigError, validate

pytest.importorskip("snakemake")
pytest.importorskip("mpi4py")

SCHEMA = ROOT / "workflows" / "schemas" / "mpi.schema.yaml"


def config() -> dict:
    return yaml.safe_load((ROOT / "config" / "mpi.yaml").read_text())


def test_config_times_both_methods_at_a_million_dofs():
    cfg = validate(config(), SCHEMA)
    assert cfg["method"] == "fetidp" and cfg["ranks"] == [1, 2]
    assert (cfg["subdomains"] * cfg["elements"] + 1) ** 2 >= 1_000_000                       # one body
    assert 2 * (cfg["contact"]["subdomains"] * cfg["contact"]["elements"] + 1) ** 2 >= 1_000_000  # two membranes


@pytest.mark.parametrize("change, where", [({"contact": {"subdomains": 4}}, "contact"),
                                           ({"contact": {"subdomains": 4, "elements": 4, "method": "smalbe"}},
                                            "contact"),
                                           ({"contact": {"subdomains": 1, "elements": 4}}, "contact/subdomains")])
def test_schema_rejects(change, where):
    with pytest.raises(ConfigError, match=where):
        validate({**config(), **change}, SCHEMA)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return copy_workflow(tmp_path_factory.mktemp("mpi"))


def test_dry_run_plans_each_method_and_rank_count(workdir):
    proc = snakemake(workdir, "-n", "--cores", "2", "--configfile", "config/mpi.yaml")
    counts = {rule: int(n) for rule, n in re.findall(r"^(\w+)\s+(\d+)\s*$", proc.stdout + proc.stderr,
                                                      flags=re.MULTILINE)}
    assert counts["mpi_case"] == 4 and counts["mpi_summary"] == 1


@pytest.mark.skipif(shutil.which("mpiexec") is None, reason="needs mpiexec (pip install mpich)")
def test_tiny_study_runs(workdir):
    (workdir / "tiny.yaml").write_text(yaml.safe_dump({
        "kind": "mpi", "study": "tiny_mpi", "method": "fetidp", "subdomains": 4, "elements": 4,
        "ranks": [1, 2], "contact": {"subdomains": 2, "elements": 4}}))
    snakemake(workdir, "--cores", "2", "--configfile", "tiny.yaml")
    table = pd.read_csv(workdir / "reports" / "tiny_mpi" / "mpi.csv")
    assert list(zip(table["problem"], table["method"], table["ranks"])) == [
        ("poisson", "fetidp", 1), ("poisson", "fetidp", 2), ("contact", "active-set", 1), ("contact", "active-set", 2)]
    for _, rows in table.groupby("method"):        # the distributed runs take the serial iterations
        assert rows["iterations"].nunique() == 1 and rows["speedup_solve"].iloc[0] == 1.0
    contact = table[table["problem"] == "contact"]
    assert (contact["ndof"] == 2 * 9 ** 2 - 9).all()                 # two 9 x 9 grids, one side clamped
    assert (contact.loc[contact["ranks"] == 2, "messages_per_iteration"] > 0).all()
    assert table["speedup_vs_serial"].gt(0).all()                    # the serial peer was measured
    for _, row in table.iterrows():     # P = 2: speed-up against one rank timed in the same job, alternating
        peer = json.loads((workdir / "results" / "tiny_mpi" / row["method"] / f"P{row['ranks']}.json").read_text())
        if row["ranks"] == 1:
            assert "peer" not in peer and row["peer_solve_seconds"] == row["solve_seconds"]
        else:
            assert peer["peer"]["iterations"] == row["iterations"] and peer["peer"]["solve_seconds"] > 0
            assert row["peer_solve_seconds"] == pytest.approx(peer["peer"]["solve_seconds"], rel=1e-12)
            assert row["speedup_solve"] == pytest.approx(row["peer_solve_seconds"] / row["solve_seconds"], rel=1e-12)
    for peaks, ranks in zip(table["peak_rss_mb"].astype(str), table["ranks"]):   # one peak per rank
        assert len(peaks.split("/")) == ranks and all(float(x) > 0 for x in peaks.split("/"))
    text = (workdir / "reports" / "tiny_mpi" / "mpi.md").read_text()
    assert "## Alpha-beta model (a model, not a measurement)" in text
    assert "## The active set method (contact problem (3.1))" in text and "(measured only)" in text
