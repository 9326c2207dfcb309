"""The Table 4.1 / 4.2 study (config/table_4.yaml): config schema, report tables and
figures on synthetic runs, and a tiny end-to-end Snakemake run of a multibody study."""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml

from ddsolve.report import plots, tables

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "workflows" / "schemas" / "config.schema.yaml"


def load_config(*names: str) -> dict:
    """config/default.yaml updated by the given files, as Snakemake merges them."""
    config = yaml.safe_load((ROOT / "config" / "default.yaml").read_text())
    for name in names:
        config.update(yaml.safe_load((ROOT / "config" / name).read_text()))
    return config


def validate(config: dict) -> dict:
    from snakemake.utils import validate as snakemake_validate

    snakemake_validate(config, str(SCHEMA))
    return config


def thesis_dir() -> Path:
    return (ROOT / load_config("table_4.yaml")["thesis_tables"]).resolve()


# --- config -------------------------------------------------------------------------------

def test_table_4_config_validates():
    config = validate(load_config("table_4.yaml"))
    assert config["study"] == "table_4" and config["problem"] == "multibody"
    assert config["methods"] == ["feti-feti", "hybrid"] and config["contacts"] == ["full", "middle"]
    assert config["rtol"] == 1e-6 and config["cond"] is True and config["check"] is False
    sweeps = config["sweeps"]
    assert sweeps[0]["bodies"] == [2, 4, 6, 8, 10, 12]
    assert sweeps[1]["subdomains"] == list(range(4, 19, 2))
    assert sweeps[2]["elements"] == [4, 8, 16, 32, 64, 128]


MULTIBODY = {"study": "m", "problem": "multibody", "methods": ["feti-feti"], "contacts": ["full"],
             "sweeps": [{"bodies": 2, "subdomains": [2, 4], "elements": 2}], "thesis_tables": "t"}


@pytest.mark.parametrize("change", [
    {"methods": ["fetidp"]},                                       # a poisson method
    {"contacts": ["half"]},                                        # unknown contact area
    {"contacts": []},
    {"sweeps": [{"bodies": 2, "subdomains": 2, "elements": 1}]},   # H_s/h below 2
    {"sweeps": [{"bodies": [0], "subdomains": 2, "elements": 2}]},
    {"sweeps": [{"subdomains": 2}]},                               # elements missing
    {"sweeps": [{"subdomains": 2, "elements": 2, "contact": "full"}]},  # unknown key
    {"sweeps": []},
    {"contacts": None},                                            # required for multibody
    {"thesis_tables": None},                                       # required for multibody
    {"sweeps": None},                                              # no cases at all
])
def test_schema_rejects_bad_multibody_config(change):
    from snakemake.exceptions import WorkflowError

    config = {**MULTIBODY, **change}
    config = {k: v for k, v in config.items() if v is not None}
    with pytest.raises(WorkflowError):
        validate(config)


def test_schema_accepts_minimal_multibody_and_rejects_contacts_for_poisson():
    from snakemake.exceptions import WorkflowError

    validate(dict(MULTIBODY))
    grid = {k: v for k, v in MULTIBODY.items() if k != "sweeps"}
    validate({**grid, "bodies": [2, 3], "subdomains": [2], "elements": [2]})  # a grid, no sweeps
    with pytest.raises(WorkflowError):
        validate({"study": "p", "methods": ["feti"], "subdomains": [2], "elements": [4],
                  "contacts": ["full"]})
    with pytest.raises(WorkflowError):
        validate({"study": "p", "methods": ["feti-feti"], "subdomains": [2], "elements": [4]})


# --- report tables and figures on synthetic runs --------------------------------------------

THESIS_4_1 = pd.DataFrame({
    "inv_Hb": [2, 4, 2, 2], "Hb_over_Hs": [2, 2, 4, 2], "Hs_over_h": [2, 2, 2, 4],
    "cond_I": [2.5536, 3.6188, 7.1076, 4.5201], "iter_I": [7, 12, 10, 9],
    "cond_II": [1.9940, 2.8136, 4.9790, 4.2654], "iter_II": [7, 10, 9, 9],
})
THESIS_4_2 = THESIS_4_1[["inv_Hb", "Hb_over_Hs", "Hs_over_h"]].assign(iter_I=[10, 12, 10, 11],
                                                                        iter_II=[10, 11, 10, 13])


def runs() -> pd.DataFrame:
    """Synthetic runs: ours = thesis * (1 + 1%) for cond, iterations + 1; one extra case."""
    rows = []
    for method in ("feti-feti", "hybrid"):
        for contact, case in (("full", "I"), ("middle", "II")):
            for _, t in THESIS_4_1.iterrows():
                rows.append({"method": method, "contact": contact, "bodies": t.inv_Hb,
                             "subdomains": t.Hb_over_Hs, "elements": t.Hs_over_h,
                             "cond": t[f"cond_{case}"] * 1.01, "iterations": t[f"iter_{case}"] + 1,
                             "converged": True})
            rows.append({"method": method, "contact": contact, "bodies": 2, "subdomains": 2,
                         "elements": 256, "cond": 30.0, "iterations": 40, "converged": False})
    return pd.DataFrame(rows).sample(frac=1.0, random_state=1)  # order must not matter


def test_multibody_table_side_by_side():
    table = tables.multibody_table(runs(), THESIS_4_1, method="feti-feti")
    assert table.index.names == ["1/H_b", "H_b/H_s", "H_s/h"]
    # the thesis's row order, then our extra case
    assert list(table.index) == [(2, 2, 2), (4, 2, 2), (2, 4, 2), (2, 2, 4), (2, 2, 256)]
    quantities = ["cond", "cond_thesis", "cond_dev", "iterations", "iterations_thesis", "iterations_dev"]
    assert list(table.columns) == [("(I)", q) for q in quantities] + [("(II)", q) for q in quantities]
    row = table.loc[(2, 2, 2)]
    assert row[("(I)", "cond_thesis")] == 2.5536
    assert row[("(I)", "cond")] == pytest.approx(2.5536 * 1.01)
    assert row[("(I)", "cond_dev")] == pytest.approx(0.01)
    assert row[("(II)", "iterations")] == 8 and row[("(II)", "iterations_thesis")] == 7
    assert row[("(II)", "iterations_dev")] == pytest.approx(1 / 7)
    assert math.isnan(table.loc[(2, 2, 256), ("(I)", "cond_thesis")])

    text = tables.to_markdown(table)
    assert "(I) cond thesis" in text and "(II) iter dev." in text and "1/H_b" in text
    assert "2.5536" in text and "+1.0%" in text and "+14.3%" in text
    assert " 40* |" in text and "* not converged" in text
    tex = tables.to_latex(table)
    assert "\\multicolumn{6}{c}{(I)}" in tex and "$H_b/H_s$" in tex and "+1.0\\%" in tex


def test_multibody_table_hybrid_iterations_only_and_order():
    order = [(2, 2, 4), (2, 2, 2)]
    table = tables.multibody_table(runs(), THESIS_4_2, method="hybrid", quantities=["iterations"],
                                   order=order)
    assert list(table.index)[:2] == order
    assert list(table.columns.get_level_values(1)) == ["iterations", "iterations_thesis",
                                                       "iterations_dev"] * 2
    assert table.loc[(2, 2, 4), ("(II)", "iterations_thesis")] == 13


def test_multibody_table_missing_method_contact_and_thesis_column():
    df = runs()
    df = df[df.contact == "full"]
    table = tables.multibody_table(df, THESIS_4_2, method="feti-feti")  # no cond in table 4.2
    assert ("(I)", "cond_thesis") not in table.columns and ("(I)", "cond") in table.columns
    assert table[("(II)", "cond")].isna().all()  # no middle runs
    assert tables.multibody_table(df, THESIS_4_1, method="hybrid2").empty
    assert "-" in tables.to_markdown(tables.multibody_table(df, None, method="hybrid2"))


def test_plot_multibody_sweep(tmp_path):
    df = runs()
    out = tmp_path / "fig.png"
    fits = plots.plot_multibody_sweep(df, THESIS_4_1, out, method="feti-feti", x="subdomains", y="cond",
                                      base=(2, 2, 2), model="linear")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert set(fits) == {("(I)", "ours"), ("(I)", "thesis"), ("(II)", "ours"), ("(II)", "thesis")}
    (slope, intercept), r2 = fits[("(I)", "thesis")]  # two points: (2, 2.5536), (4, 7.1076)
    assert slope == pytest.approx((7.1076 - 2.5536) / 2) and r2 == pytest.approx(1.0)
    (slope_ours, _), _ = fits[("(I)", "ours")]
    assert slope_ours == pytest.approx(1.01 * slope)
    # the hybrid figure: iterations against H_s/h, a + b log x
    fits = plots.plot_multibody_sweep(df, THESIS_4_2, tmp_path / "hyb.png", method="hybrid", x="elements",
                                      y="iterations", base=(2, 2, 2), model="log_linear", logx=True)
    (a, b), _ = fits[("(I)", "thesis")]  # (2, 10), (4, 11)
    assert b == pytest.approx(1 / math.log(2))
    assert (tmp_path / "hyb.png").is_file()


# --- the pipeline ----------------------------------------------------------------------------

TINY = """\
study: tiny4
problem: multibody
methods: [feti-feti]
contacts: [full, middle]
sweeps:
  - {bodies: 2, subdomains: 2, elements: 2}
check: false
thesis_tables: THESIS
"""


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    pytest.importorskip("snakemake")
    wd = tmp_path_factory.mktemp("table4")
    shutil.copy(ROOT / "Snakefile", wd / "Snakefile")
    shutil.copytree(ROOT / "workflows", wd / "workflows", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "config", wd / "config")
    return wd


def test_dry_run_table_4(workdir):
    from test_pipeline import planned, snakemake

    (workdir / "thesis.yaml").write_text(f"thesis_tables: {thesis_dir()}\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "thesis.yaml")
    text = proc.stdout + proc.stderr
    assert planned(proc)["solve_case"] == 20 * 2 * 2
    assert "results/table_4/feti-feti/middle/Nb2_Ns18_m2.h5" in text
    assert "results/table_4/hybrid/full/Nb12_Ns2_m2.h5" in text
    assert "reports/table_4/table_4_2.md" in text and "reports/table_4/figure_hybrid_iterations.png" in text
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "thesis.yaml",
                     "--config", "methods=[feti-feti]")
    text = proc.stdout + proc.stderr
    assert planned(proc)["solve_case"] == 40
    assert "table_4_1.md" in text and "figure_4_3.png" in text
    assert "table_4_2" not in text and "figure_hybrid_iterations" not in text


@pytest.mark.skipif(not (thesis_dir() / "table_4_1.csv").is_file(), reason="thesis transcriptions not found")
def test_tiny_multibody_study_end_to_end(workdir):
    from test_pipeline import planned, snakemake

    (workdir / "tiny.yaml").write_text(TINY.replace("THESIS", str(thesis_dir())))
    snakemake(workdir, "--cores", "2", "--configfile", "tiny.yaml")
    for contact in ("full", "middle"):
        assert (workdir / "results" / "tiny4" / "feti-feti" / contact / "Nb2_Ns2_m2.h5").is_file()
    df = pd.read_csv(workdir / "results" / "tiny4" / "summary.csv")
    assert sorted(df["contact"]) == ["full", "middle"] and df["converged"].all()
    reports = workdir / "reports" / "tiny4"
    table = (reports / "table_4_1.md").read_text()
    assert "2.5536" in table and "1.9940" in table and "(II) cond dev." in table
    assert "2.5536" in (reports / "table_4_1.tex").read_text()
    assert not (reports / "table_4_2.md").exists()  # no hybrid runs: no table 4.2
    for figure in ("figure_4_2", "figure_4_3"):
        assert (reports / f"{figure}.png").read_bytes()[:4] == b"\x89PNG"

    again = snakemake(workdir, "-n", "--cores", "1", "--configfile", "tiny.yaml")
    assert "Nothing to be done" in again.stdout + again.stderr
    (workdir / "more.yaml").write_text("sweeps: [{bodies: 2, subdomains: 2, elements: [2, 4]}]\n")
    more = planned(snakemake(workdir, "-n", "--cores", "1", "--configfile", "tiny.yaml", "more.yaml"))
    assert more["solve_case"] == 2  # only the new case, both contacts
    (workdir / "rtol.yaml").write_text("rtol: 1.0e-8\n")
    rerun = planned(snakemake(workdir, "-n", "--cores", "1", "--configfile", "tiny.yaml", "rtol.yaml"))
    assert rerun["solve_case"] == 2


def test_poisson_study_with_several_bodies_is_rejected(workdir):
    from test_pipeline import snakemake

    (workdir / "bodies.yaml").write_text("study: b\nsweeps: [{bodies: [1, 2], subdomains: 2, elements: 4}]\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "bodies.yaml", check=False)
    assert proc.returncode != 0 and "exactly one body" in proc.stdout + proc.stderr
