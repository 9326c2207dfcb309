"""The Table 4.1 / 4.2 study (config/table_4.yaml): config schema, report tables and
figures on synthetic runs, and a tiny end-to-end Snakemake run of a multibody study."""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest
import yaml

from ddstudies.report import plots, tables

from conftest import ROOT  # noqa: E402
SCHEMA = ROOT / "workflows" / "schemas" / "config.schema.yaml"


def load_config(*names: str) -> dict:
    """The given single-study config files, merged as Snakemake merges them (top-level keys)."""
    config = {}
    for name in names:
        config.update(yaml.safe_load((ROOT / "config" / name).read_text()))
    return config


def validate(config: dict) -> dict:
    """The workflow's validation: the schema with the option lists of ddsolve.options injected."""
    from ddstudies.workflow import validate as workflow_validate

    return workflow_validate(config, SCHEMA)


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
    assert sweeps[2] == {"bodies": 2, "subdomains": [24, 32, 48], "elements": 2}  # beyond the thesis
    assert sweeps[3]["elements"] == [4, 8, 16, 32, 64, 128]


MULTIBODY = {"kind": "table_4", "study": "m", "problem": "multibody", "methods": ["feti-feti"], "contacts": ["full"],
             "sweeps": [{"bodies": 2, "subdomains": [2, 4], "elements": 2}], "thesis_tables": "t",
             "tables": {"table_4_1": {"method": "feti-feti", "quantities": ["cond"], "title": "T"}},
             "figures": {"figure_4_2": {"method": "feti-feti", "x": "subdomains", "y": "cond", "title": "F"}}}


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
    from ddstudies.workflow import ConfigError as WorkflowError

    config = {**MULTIBODY, **change}
    config = {k: v for k, v in config.items() if v is not None}
    with pytest.raises(WorkflowError):
        validate(config)


def test_schema_accepts_minimal_multibody_and_rejects_contacts_for_poisson():
    from ddstudies.workflow import ConfigError as WorkflowError

    validate(dict(MULTIBODY))
    grid = {k: v for k, v in MULTIBODY.items() if k != "sweeps"}
    validate({**grid, "bodies": [2, 3], "subdomains": [2], "elements": [2]})  # a grid, no sweeps
    with pytest.raises(WorkflowError):
        validate({"kind": "grid", "study": "p", "methods": ["feti"], "subdomains": [2], "elements": [4],
                  "contacts": ["full"]})
    with pytest.raises(WorkflowError):
        validate({"kind": "grid", "study": "p", "methods": ["feti-feti"], "subdomains": [2], "elements": [4]})


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


def hbhs_runs() -> pd.DataFrame:
    """Synthetic H_b/H_s sweep from (2, 2, 2): FETI-FETI cond = 2.5 x - 3, iterations = 2 + 4 sqrt(x),
    hybrid iterations = 10 + 4 log(2 x), both contacts; x = 24 is beyond the thesis's tables."""
    rows = []
    for contact in ("full", "middle"):
        for x in (2, 4, 8, 16, 24):
            rows.append({"method": "feti-feti", "contact": contact, "bodies": 2, "subdomains": x,
                         "elements": 2, "cond": 2.5 * x - 3, "iterations": 2 + 4 * math.sqrt(x),
                         "converged": True})
            rows.append({"method": "hybrid", "contact": contact, "bodies": 2, "subdomains": x,
                         "elements": 2, "cond": math.nan,
                         "iterations": 10 + 4 * math.log(2 * x) if x != 24 else 17,    # capped at maxiter 17
                         "converged": x != 24})
    rows.append({"method": "hybrid", "contact": "full", "bodies": 4, "subdomains": 4, "elements": 2,
                 "cond": math.nan, "iterations": 99, "converged": True})  # not on the sweep
    return pd.DataFrame(rows)


def test_fit_sqrt_linear():
    a, b, r2 = plots.fit_sqrt_linear([1, 4, 9, 16], [5, 7, 9, 11])
    assert (a, b, r2) == (pytest.approx(3), pytest.approx(2), pytest.approx(1))
    assert all(math.isnan(v) for v in plots.fit_sqrt_linear([4], [1]))
    with pytest.raises(ValueError):
        plots.fit_sqrt_linear([-1, 4], [1, 2])


def test_hbhs_growth_laws_ratios_and_crossing():
    growth = plots.hbhs_growth(hbhs_runs(), base=(2, 2, 2))
    assert list(growth["case"]) == ["(I)"] * 3 + ["(II)"] * 3
    g = growth.set_index(["case", "method", "quantity"])
    cond = g.loc[("(I)", "feti-feti", "cond")]
    assert (cond["from"], cond["to"]) == (4, 24)
    assert cond["at_from"] == 7 and cond["at_to"] == 57 and cond["ratio"] == pytest.approx(57 / 7)
    assert (cond["a"], cond["b"], cond["r2"]) == (pytest.approx(-3), pytest.approx(2.5), pytest.approx(1))
    it = g.loc[("(II)", "feti-feti", "iterations")]
    assert (it["a"], it["b"]) == (pytest.approx(2), pytest.approx(4))
    hyb = g.loc[("(I)", "hybrid", "iterations")]  # the law is in H_b/h = 2 H_b/H_s
    assert (hyb["a"], hyb["b"], hyb["r2"]) == (pytest.approx(10), pytest.approx(4), pytest.approx(1))
    assert hyb["to"] == 16          # the run at 24 stopped at maxiter (17): left out (a review, 2026-11-28)
    # 2 + 4 sqrt(x) = 10 + 4 log(2x) at x ~ 36.4 (found numerically)
    x = hyb["crossing"]
    assert 2 + 4 * math.sqrt(x) == pytest.approx(10 + 4 * math.log(2 * x), abs=1e-3)
    assert math.isnan(cond["crossing"])
    # without FETI-FETI runs: hybrid rows only, no crossing; a missing start falls back to the smallest
    only = plots.hbhs_growth(hbhs_runs().query("method == 'hybrid'"), base=(2, 2, 2), contacts=["full"],
                             start=3, end=16)
    assert len(only) == 1 and (only.at[0, "from"], only.at[0, "to"]) == (2, 16)
    assert math.isnan(only.at[0, "crossing"])
    text = tables.to_markdown(tables.growth_table(growth))
    assert "4 → 24" in text and "7.00 → 57.00" in text and "a + b·√(H_b/H_s)" in text
    # R^2 of a law fitted through two points is 1 by construction: the table says so (as the figures do)
    assert (growth["points"] > 2).all() and "1.000" in text and "exact" not in text
    two = plots.hbhs_growth(hbhs_runs().query("subdomains in [4, 8]"), base=(2, 2, 2))
    assert (two["points"] == 2).all()
    two_text = tables.to_markdown(tables.growth_table(two))
    assert "exact, 2 points" in two_text and "1.000" not in two_text
    assert "a + b·log(H_b/h)" in text and f"{x:.0f}" in text and "×8.14" in text
    # the LaTeX twin is ASCII (pdflatex's utf8 input has no glyph for → √ ² × ·; a review)
    tex = tables.to_latex(tables.growth_table(growth))
    assert tex.isascii() and "4 $\\to$ 24" in tex and "$\\surd$" in tex and "$\\times$8.14" in tex


def test_hbhs_sweep_table_marks_rows_beyond_the_thesis():
    df = hbhs_runs()
    thesis = {"feti-feti": THESIS_4_1, "hybrid": THESIS_4_2}
    table = tables.hbhs_sweep_table(df, thesis, base=(2, 2, 2))
    assert list(table.index) == [2, 4, 8, 16, 24] and table.index.name == "H_b/H_s"
    assert list(table.columns[:6]) == [("(I) FETI-FETI", q) for q in
                                       ("cond", "cond_thesis", "iterations", "iterations_thesis")] + [
        ("(I) hybrid", "iterations"), ("(I) hybrid", "iterations_thesis")]
    assert table.at[4, ("(II) FETI-FETI", "cond_thesis")] == 4.9790
    assert table.at[4, ("(I) hybrid", "iterations_thesis")] == 10
    text = tables.to_markdown(table)
    assert "(I) FETI-FETI cond thesis" in text and "(II) hybrid iter" in text
    assert "57.0000†" in text and "† beyond the thesis's table" in text
    assert "8* |" not in text and "*†" in text and "* not converged" in text  # 24: both marks
    assert "\\multicolumn{4}{c}{(I) FETI-FETI}" in tables.to_latex(table)
    assert tables.hbhs_sweep_table(df[df.method == "none"], thesis, base=(2, 2, 2)).empty


def test_mark_beyond_thesis_on_table_4_layout():
    table = tables.multibody_table(runs(), THESIS_4_1, method="feti-feti")
    assert tables.mark_beyond_thesis(table) == [(2, 2, 256)]
    text = tables.to_markdown(table)
    assert " 40*† |" in text and "30.0000† |" in text and "† beyond the thesis's table" in text
    assert tables.mark_beyond_thesis(tables.multibody_table(runs(), None, method="feti-feti")) == []


def test_plot_iterations_vs_HbHs(tmp_path):
    out = tmp_path / "growth.png"
    fits = plots.plot_iterations_vs_HbHs(hbhs_runs(), {"feti-feti": THESIS_4_1, "hybrid": THESIS_4_2},
                                         out, base=(2, 2, 2))
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert set(fits) == {(c, m) for c in ("(I)", "(II)") for m in ("feti-feti", "hybrid")}
    (a, b), r2 = fits[("(I)", "feti-feti")]
    assert (a, b, r2) == (pytest.approx(2), pytest.approx(4), pytest.approx(1))
    (a, b), _ = fits[("(II)", "hybrid")]
    assert (a, b) == (pytest.approx(10), pytest.approx(4))
    # no thesis, one contact, no FETI-FETI runs
    fits = plots.plot_iterations_vs_HbHs(hbhs_runs().query("method == 'hybrid'"), None,
                                         tmp_path / "h.png", base=(2, 2, 2), contacts=["middle"])
    assert set(fits) == {("(II)", "hybrid")} and (tmp_path / "h.png").is_file()


# --- the pipeline ----------------------------------------------------------------------------

TINY = """\
study: tiny4
problem: multibody
methods: [feti-feti]
contacts: [full, middle]
presets: [default]   # first the default rule set alone; the test then adds the thesis preset
sweeps:
  - {bodies: 2, subdomains: 2, elements: 2}
check: false
thesis_tables: THESIS
"""


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    pytest.importorskip("snakemake")
    from conftest import copy_workflow

    return copy_workflow(tmp_path_factory.mktemp("table4"))


def test_dry_run_table_4(workdir):
    from conftest import planned, run_snakemake as snakemake

    (workdir / "thesis.yaml").write_text(f"thesis_tables: {thesis_dir()}\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "thesis.yaml")
    text = proc.stdout + proc.stderr
    assert planned(proc)["solve_case"] == 23 * 2 * 2 * 2   # cases x contacts x methods x presets
    assert "results/table_4/feti-feti/middle/Nb2_Ns18_m2.h5" in text
    assert "results/table_4/feti-feti/middle/Nb2_Ns18_m2_thesis.h5" in text   # the thesis preset's run
    assert "preset_tag=_thesis" in text
    assert "results/table_4/hybrid/full/Nb12_Ns2_m2.h5" in text
    assert "results/table_4/hybrid/middle/Nb2_Ns48_m2.h5" in text  # beyond the thesis's table
    assert "reports/table_4/table_4_2.md" in text and "reports/table_4/figure_4_3.png" in text
    assert "reports/table_4/table_4_growth.md" in text and "figure_iterations_vs_HbHs.png" in text
    assert "reports/table_4/table_4_2_optimal.md" in text and "reports/table_4/table_4_1_readings.md" in text
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "thesis.yaml",
                     "--config", "methods=[feti-feti]")
    text = proc.stdout + proc.stderr
    assert planned(proc)["solve_case"] == 46 * 2
    assert "table_4_1.md" in text and "figure_4_2_hs.png" in text
    assert "table_4_2" not in text and "figure_4_3" not in text
    assert "table_4_growth" not in text and "figure_iterations_vs_HbHs" not in text
    assert "table_4_1_readings.md" in text   # FETI-FETI's exact spectra under the thesis's readings


@pytest.mark.slow
@pytest.mark.skipif(not (thesis_dir() / "table_4_1.csv").is_file(), reason="thesis transcriptions not found")
def test_tiny_multibody_study_end_to_end(workdir):
    from conftest import planned, run_snakemake as snakemake

    (workdir / "tiny.yaml").write_text(TINY.replace("THESIS", str(thesis_dir())))
    snakemake(workdir, "--cores", "2", "--configfile", "config/table_4.yaml", "tiny.yaml")
    for contact in ("full", "middle"):
        assert (workdir / "results" / "tiny4" / "feti-feti" / contact / "Nb2_Ns2_m2.h5").is_file()
    df = pd.read_csv(workdir / "results" / "tiny4" / "summary.csv")
    assert sorted(df["contact"]) == ["full", "middle"] and df["converged"].all()
    reports = workdir / "reports" / "tiny4"
    table = (reports / "table_4_1.md").read_text()
    assert "2.5536" in table and "1.9940" in table and "(II) cond dev." in table
    alone = [[cell.strip() for cell in line.split("|")[1:-1]] for line in table.splitlines() if line.startswith("|")]
    assert alone[0][3] == "(I) cond" and "rule set" not in table   # one rule set: no rule-set column
    assert "2.5536" in (reports / "table_4_1.tex").read_text()
    assert not (reports / "table_4_2.md").exists()  # no hybrid runs: no table 4.2
    readings = (reports / "table_4_1_readings.md").read_text()
    assert "| 2 | 2 | 2 | I | weighted | all | full |" in readings and "thesis 2.5536" in readings
    for figure in ("figure_4_2", "figure_4_2_hs"):
        assert (reports / f"{figure}.png").read_bytes()[:4] == b"\x89PNG"

    again = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "tiny.yaml")
    assert "Nothing to be done" in again.stdout + again.stderr
    # ProblemSpec's defaults written out are no change (they reran every finished case: a review)
    again = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "tiny.yaml",
                      "--config", "norm=l2", "projection=orthogonal", "preset=default")
    assert "Nothing to be done" in again.stdout + again.stderr
    (workdir / "more.yaml").write_text("sweeps: [{bodies: 2, subdomains: 2, elements: [2, 4]}]\n")
    more = planned(snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "tiny.yaml", "more.yaml"))
    assert more["solve_case"] == 2  # only the new case, both contacts
    (workdir / "rtol.yaml").write_text("rtol: 1.0e-8\n")
    rerun = planned(snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "tiny.yaml", "rtol.yaml"))
    assert rerun["solve_case"] == 2

    # the thesis preset beside the default: only its new cases run, Table 4.1 shows both rule sets
    (workdir / "presets.yaml").write_text("presets: [default, thesis]\n")
    both = ("--configfile", "config/table_4.yaml", "tiny.yaml", "presets.yaml")
    plan = snakemake(workdir, "-n", "--cores", "1", *both)
    assert planned(plan)["solve_case"] == 2   # full and middle under the thesis preset; no default rerun
    assert "Nb2_Ns2_m2_thesis.h5" in plan.stdout + plan.stderr
    snakemake(workdir, "--cores", "2", *both)
    df = pd.read_csv(workdir / "results" / "tiny4" / "summary.csv")
    assert sorted(zip(df["preset"], df["contact"])) == [("default", "full"), ("default", "middle"),
                                                        ("thesis", "full"), ("thesis", "middle")]
    table = (reports / "table_4_1.md").read_text()
    rows = [[cell.strip() for cell in line.split("|")[1:-1]] for line in table.splitlines() if line.startswith("|")]
    assert rows[0][3] == "rule set" and [row[3] for row in rows[2:]] == ["default", "thesis"]
    assert rows[2][4] == alone[2][3]   # the default's (I) cond: the run made before, not recomputed
    assert rows[2][5] == rows[3][5] == "2.5536"   # each rule set beside the thesis's value
    assert "2.5536" in table and "Rule sets:" in table   # the computed closer-to-the-thesis note

    # cond: false (common.smk table_4_params): Table 4.1 without its cond columns, and the legend says why (only
    # the table jobs rerun: the cases are not re-solved for this check)
    snakemake(workdir, "--cores", "2", *both, "--config", "cond=false", "--rerun-triggers", "mtime",
              "--forcerun", "table_4")
    table = (reports / "table_4_1.md").read_text()
    header = next(line for line in table.splitlines() if line.startswith("|"))
    assert "no condition estimates: the study sets cond: false" in table
    assert "(I) iter" in header and "cond" not in header, header


def run_script(name: str, **attrs) -> None:
    """Run a workflow script in-process with a stand-in ``snakemake`` object (fast; the rule
    wiring is checked by the dry runs). The scripts redirect stdout/stderr to their log."""
    import sys
    from types import SimpleNamespace

    sm = SimpleNamespace(**{k: SimpleNamespace(**v) if isinstance(v, dict) else v for k, v in attrs.items()})
    path = ROOT / "workflows" / "scripts" / name
    stdout, stderr = sys.stdout, sys.stderr
    try:
        exec(compile(path.read_text(), str(path), "exec"), {"snakemake": sm, "__name__": "__main__"})
    finally:
        sys.stdout, sys.stderr = stdout, stderr


def test_scripts_render_reports_beyond_the_thesis(tmp_path):
    summary = tmp_path / "summary.csv"
    hbhs_runs().to_csv(summary, index=False)
    thesis = []
    for name, frame in (("table_4_1", THESIS_4_1), ("table_4_2", THESIS_4_2)):
        thesis.append(str(tmp_path / f"{name}.csv"))
        frame.to_csv(thesis[-1], index=False)
    common = {"wildcards": {"study": "s"}, "input": {"summary": str(summary), "thesis": thesis}}
    growth = {"method": "hybrid", "kind": "growth", "start": 4, "title": "Beyond"}
    out = {"md": str(tmp_path / "g.md"), "tex": str(tmp_path / "g.tex")}
    run_script("make_table_4.py", **common, output=out, log=[str(tmp_path / "g.log")],
               params={"table": growth, "contacts": ["full", "middle"], "cases": [], "base": [2, 2, 2]})
    text = Path(out["md"]).read_text()
    assert text.startswith("# Beyond (study `s`)") and "Rows marked † (8, 16, 24)" in text
    assert "## Growth in H_b/H_s" in text and "4 → 24" in text and "(II) hybrid iter thesis" in text
    assert "\\multicolumn{4}{c}{(II) FETI-FETI}" in Path(out["tex"]).read_text()

    table_4_2 = {"method": "hybrid", "quantities": ["iterations"], "title": "Table 4.2"}
    run_script("make_table_4.py", **{**common, "input": {"summary": str(summary), "thesis": thesis[1]}},
               output=out, log=[str(tmp_path / "t.log")],
               params={"table": table_4_2, "contacts": ["full"], "cases": [[2, 2, 2]], "base": [2, 2, 2]})
    text = Path(out["md"]).read_text()
    assert "Rows marked † ((2, 8, 2); (2, 16, 2); (2, 24, 2); (4, 4, 2)) go beyond" in text
    assert "99.0000† |" in text and "17.0000*† |" in text and "value). " not in text

    figure = {"method": "hybrid", "kind": "growth", "title": "Iterations"}
    png = tmp_path / "f.png"
    run_script("plot_figure_4.py", **common, output=[str(png)], log=[str(tmp_path / "f.log")],
               params={"figure": figure, "contacts": ["full", "middle"], "base": [2, 2, 2]})
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert "(II) hybrid: a, b = (10.0, 4.0) R2=1.0000" in (tmp_path / "f.log").read_text()


def test_tables_without_condition_estimates(tmp_path):
    """A study with cond: false rendered Table 4.1 and the growth table with cond columns of dashes and no
    word why (a review): the rule passes the entry without cond (``table_4_params``), the legend says why."""
    summary = tmp_path / "summary.csv"
    hbhs_runs().assign(cond=math.nan).to_csv(summary, index=False)
    thesis = []
    for name, frame in (("table_4_1", THESIS_4_1), ("table_4_2", THESIS_4_2)):
        thesis.append(str(tmp_path / f"{name}.csv"))
        frame.to_csv(thesis[-1], index=False)
    out = {"md": str(tmp_path / "t.md"), "tex": str(tmp_path / "t.tex")}
    specs = [({"method": "feti-feti", "quantities": ["iterations"], "cond": False, "title": "T"}, thesis[0]),
             ({"method": "hybrid", "kind": "growth", "start": 4, "cond": False, "title": "G"}, thesis)]
    for spec, inputs in specs:
        run_script("make_table_4.py", wildcards={"study": "s"}, input={"summary": str(summary), "thesis": inputs},
                   output=out, log=[str(tmp_path / "t.log")],
                   params={"table": spec, "contacts": ["full", "middle"], "cases": [[2, 2, 2]], "base": [2, 2, 2]})
        text = Path(out["md"]).read_text()
        header = next(line for line in text.splitlines() if line.startswith("|"))
        assert "iter" in header and "cond" not in header, header
        assert "no condition estimates: the study sets cond: false" in text
        assert "cond: Lanczos estimate" not in text
    quantities = {line.split("|")[3].strip() for line in text.splitlines()[-4:]}
    assert quantities == {"iter"}                                     # the growth rows: iterations only


def test_the_legend_names_the_hybrid_norm_used(tmp_path):
    """Table 4.2's legend said ||.||_2 whatever the study's norm (a review: a norm: M study)."""
    summary = tmp_path / "summary.csv"
    hbhs_runs().assign(norm="M", projection="lumped").to_csv(summary, index=False)
    thesis = tmp_path / "table_4_2.csv"
    THESIS_4_2.to_csv(thesis, index=False)
    out = {"md": str(tmp_path / "t.md"), "tex": str(tmp_path / "t.tex")}
    run_script("make_table_4.py", wildcards={"study": "s"}, input={"summary": str(summary), "thesis": str(thesis)},
               output=out, log=[str(tmp_path / "t.log")],
               params={"table": {"method": "hybrid", "quantities": ["iterations"], "title": "T"},
                       "contacts": ["full"], "cases": [[2, 2, 2]], "base": [2, 2, 2]})
    text = Path(out["md"]).read_text()
    assert "PCR for the hybrid method, in ||.||_M, projection lumped)" in text


def test_poisson_study_with_several_bodies_is_rejected(workdir):
    from conftest import run_snakemake as snakemake     # not via test_pipeline: this folder runs alone too

    (workdir / "bodies.yaml").write_text("kind: grid\nstudy: b\nmethods: [bddc]\n"
                                         "sweeps: [{bodies: [1, 2], subdomains: 2, elements: 4}]\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "bodies.yaml", check=False)
    assert proc.returncode != 0 and "exactly one body" in proc.stdout + proc.stderr
