"""The one-command reproduction: config/default.yaml and config/quick.yaml list studies.

Each entry is a single-study config plus overrides and runs as a Snakemake module of the
workflow (workflows/rules/reproduce.smk). These tests check the configs, the plan of the
default and quick runs, the errors for bad lists, and that a study finished by its own
config is not rerun by the reproduction.
"""
from __future__ import annotations

import re

import pytest
import yaml
from conftest import ROOT, copy_workflow
from conftest import run_snakemake as snakemake

pytest.importorskip("snakemake")

#: Every table and figure the reproduction must regenerate (the issue's list).
REQUIRED_REPORTS = [
    "reports/table_4/table_4_1.md", "reports/table_4/table_4_2.md",
    "reports/table_4/figure_4_2.png", "reports/table_4/figure_4_2_hs.png",
    "reports/table_5_6/table_5_1.md", "reports/table_5_6/table_6_1.md",
    "reports/table_5_6/figure_5_2_surface.png", "reports/table_5_6/figure_5_2_contact.png",
    "reports/bench/work_precision.png", "reports/scaling/scaling.png", "reports/stress/stress.md",
    "reports/unstructured/unstructured.png", "reports/unstructured/unstructured.md",
    "reports/unstructured/cond_law.md", "reports/unstructured/cond_law.png",
    "reports/unstructured/contact_solution.png",
]


def load(name: str) -> dict:
    return yaml.safe_load((ROOT / "config" / name).read_text())


def study_schema(entry: dict) -> tuple[dict, str]:
    """The merged config of a `studies` entry and its kind."""
    from snakemake.utils import update_config

    config = load(entry["configfile"].removeprefix("config/"))
    update_config(config, entry.get("set") or {})
    return config, config["kind"]


@pytest.mark.parametrize("name", ["default.yaml", "quick.yaml"])
def test_study_lists_validate(name):
    from ddstudies.workflow import SCHEMAS, validate

    schemas = ROOT / "workflows" / "schemas"
    studies = load(name)
    validate(studies, schemas / "studies.schema.yaml")
    names = [entry["name"] for entry in studies["studies"]]
    assert names == ["poisson", "table_4", "table_5_6", "bench", "scaling", "stress", "unstructured"]
    for entry in studies["studies"]:
        config, kind = study_schema(entry)
        validate(config, schemas / f"{SCHEMAS[kind]}.schema.yaml")
        if name == "quick.yaml":  # the smoke test writes elsewhere than the full run
            assert "quick" in config["study"]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return copy_workflow(tmp_path_factory.mktemp("reproduce"))


def jobs(text: str) -> dict[str, int]:
    return {rule: int(n) for rule, n in re.findall(r"^(\w+)\s+(\d+)\s*$", text, flags=re.MULTILINE)}


def test_default_run_plans_every_report(workdir):
    proc = snakemake(workdir, "-n", "--cores", "2")
    text = proc.stdout + proc.stderr
    for path in REQUIRED_REPORTS:
        assert path in text, path
    counts = jobs(text)
    assert counts["poisson_solve_case"] == 36 and counts["table_4_solve_case"] == 92 * 2   # presets default, thesis
    assert counts["table_5_6_solve_case"] == 50 * 2 and counts["scaling_scaling_case"] == 14
    assert counts["unstructured_unstructured_case"] == 8     # refine 0..3 of each problem (not the 1M cases)
    assert counts["unstructured_unstructured_cond_case"] == 2 * 2 * (4 + 5 - 1)   # x 2 primal sets; P to 256; refine 0..4 at P 16
    assert counts["all"] == 1
    quick = jobs((lambda p: p.stdout + p.stderr)(snakemake(workdir, "-n", "--cores", "2", "--configfile",
                                                           "config/quick.yaml")))
    assert quick["total"] < counts["total"] / 3 and quick["table_5_6_contact_table"] == 2


@pytest.mark.parametrize("studies, message", [
    ("studies: [{name: a, configfile: config/poisson.yaml}, {name: a, configfile: config/table_4.yaml}]",
     "names must be unique"),
    ("studies: [{name: a, configfile: config/nothere.yaml}]", "cannot read configfile config/nothere.yaml"),
    ("studies: [{name: 1a, configfile: config/poisson.yaml}]", "does not match"),
    ("studies: [{name: a, configfile: config/poisson.yaml, set: {study: same}}, "
     "{name: b, configfile: config/poisson.yaml, set: {study: same, methods: [bddc]}}]",
     "studies: a and b both write study 'same'"),      # was Snakemake's AmbiguousRuleException
])
def test_bad_study_lists_are_rejected(workdir, studies, message):
    (workdir / "bad.yaml").write_text(studies + "\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "bad.yaml", check=False)
    assert proc.returncode != 0 and message in proc.stdout + proc.stderr


@pytest.mark.slow
def test_study_finished_alone_is_not_rerun_by_the_reproduction(workdir):
    (workdir / "tiny.yaml").write_text("kind: grid\nstudy: tiny\nsubdomains: [2]\nelements: [2]\nmethods: [bddc]\n"
                                       "cond: false\n")
    (workdir / "repro.yaml").write_text("studies: [{name: tiny, configfile: tiny.yaml, set: {}}]\n")
    snakemake(workdir, "--cores", "1", "--configfile", "tiny.yaml")
    assert (workdir / "reports" / "tiny" / "table.md").is_file()
    again = snakemake(workdir, "-n", "--cores", "1", "--configfile", "repro.yaml")
    assert "Nothing to be done" in again.stdout + again.stderr
    # the same value written as a float (gamma: 1.0 for the schema's default 1) is the same params: no rerun
    (workdir / "repro.yaml").write_text("studies: [{name: tiny, configfile: tiny.yaml, set: {gamma: 1.0}}]\n")
    again = snakemake(workdir, "-n", "--cores", "1", "--configfile", "repro.yaml")
    assert "Nothing to be done" in again.stdout + again.stderr
    # an override in the list reruns exactly the affected cases, under the module's rule names
    (workdir / "repro.yaml").write_text("studies: [{name: tiny, configfile: tiny.yaml, set: {rtol: 1.0e-8}}]\n")
    rerun = jobs((lambda p: p.stdout + p.stderr)(snakemake(workdir, "-n", "--cores", "1", "--configfile",
                                                           "repro.yaml")))
    assert rerun["tiny_solve_case"] == 1
