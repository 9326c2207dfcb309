"""Report tables, fits and plots (ddstudies.report), and the pipeline's config schema."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import yaml

from ddstudies.report import plots, tables

from conftest import ROOT  # noqa: E402
SCHEMA = ROOT / "workflows" / "schemas" / "config.schema.yaml"


def runs() -> pd.DataFrame:
    rows = []
    for method, scale in [("feti", 1.0), ("fetidp", 0.5)]:
        for ns in (2, 4):
            for m in (4, 8):
                rows.append({"problem": "poisson", "method": method, "subdomains": ns, "elements": m,
                             "cond": round(scale * ns * (1 + math.log(m)) ** 2, 4),
                             "iterations": ns + m, "converged": True})
    df = pd.DataFrame(rows)
    df.loc[(df.method == "feti") & (df.subdomains == 4) & (df.elements == 8), "converged"] = False
    df.loc[(df.method == "fetidp") & (df.subdomains == 2) & (df.elements == 8), "cond"] = float("nan")
    return df


def test_condition_table_layout():
    table = tables.condition_table(runs(), methods=["feti", "fetidp", "bddc"])
    assert table.index.names == ["subdomains", "elements"]
    assert list(table.index) == [(2, 4), (2, 8), (4, 4), (4, 8)]
    assert list(table.columns.get_level_values(0).unique()) == ["feti", "fetidp", "bddc"]
    assert table.loc[(2, 4), ("feti", "cond")] == pytest.approx(2 * (1 + math.log(4)) ** 2, abs=1e-4)
    assert table.loc[(4, 8), ("fetidp", "iterations")] == 12
    assert table[("bddc", "cond")].isna().all()  # no runs: empty columns


def test_markdown_rendering():
    df = runs()
    text = tables.to_markdown(tables.condition_table(df))
    expected_cond = f"{df.loc[0, 'cond']:.4f}"  # feti, 1/H=2, H/h=4
    assert expected_cond in text
    assert "FETI cond" in text and "FETI-DP iter" in text and "1/H" in text and "H/h" in text
    assert " 12* |" in text  # feti, 1/H=4, H/h=8 did not converge
    assert "* not converged" in text
    # missing cond shown as '-'
    row = [line for line in text.splitlines() if line.startswith("|") and "|     2 |     8 |" in line][0]
    assert " - |" in row


def test_latex_rendering():
    table = tables.condition_table(runs())
    tex = tables.to_latex(table)
    assert "\\begin{tabular}{rrrrrr}" in tex and "\\end{tabular}" in tex
    assert "\\toprule" in tex and "\\midrule" in tex and "\\bottomrule" in tex
    assert "\\multicolumn{2}{c}{FETI-DP}" in tex and "\\cmidrule(lr){3-4}" in tex
    assert "$1/H$ & $H/h$ & cond & iter & cond & iter" in tex
    body = tex.split("\\midrule")[1].split("\\bottomrule")[0].strip().splitlines()
    assert len(body) == 4 and all(line.count("&") == 5 for line in body)
    assert "12*" in tex


def test_duplicate_runs_rejected():
    df = pd.concat([runs(), runs().iloc[[0]]])
    with pytest.raises(ValueError, match="several runs"):
        tables.condition_table(df)


def test_side_by_side_deviation_columns():
    ours = tables.flatten(tables.condition_table(runs(), methods=["feti"]))
    assert list(ours.columns) == ["subdomains", "elements", "feti_cond", "feti_iterations"]
    thesis = pd.DataFrame({"Hb_over_Hs": [2, 2, 4], "Hs_over_h": [4, 8, 4],
                           "cond_I": [ours.feti_cond[0] * 1.25, 0.0, ours.feti_cond[2]],
                           "iter_I": [5, 10, 8]})
    out = tables.side_by_side(ours, thesis, keys={"subdomains": "Hb_over_Hs", "elements": "Hs_over_h"},
                              columns={"feti_cond": "cond_I", "feti_iterations": "iter_I"})
    assert list(out.columns) == ["subdomains", "elements",
                                 "feti_cond", "feti_cond_thesis", "feti_cond_dev",
                                 "feti_iterations", "feti_iterations_thesis", "feti_iterations_dev"]
    assert len(out) == 4  # all our rows; (4, 8) has no thesis value
    assert out.feti_cond_dev[0] == pytest.approx(1 / 1.25 - 1)
    assert math.isnan(out.feti_cond_dev[1])  # thesis value 0
    assert out.feti_cond_dev[2] == pytest.approx(0.0)
    assert math.isnan(out.feti_cond_thesis[3]) and math.isnan(out.feti_cond_dev[3])
    assert out.feti_iterations_dev[0] == pytest.approx((6 - 5) / 5)
    text = tables.to_markdown(out)
    assert "+20.0%" in text and "-20.0%" in text
    assert "\\%" in tables.to_latex(out)


def test_side_by_side_same_names_and_missing_column():
    ours = pd.DataFrame({"k": [1, 2], "v": [1.0, 2.0]})
    thesis = pd.DataFrame({"k": [1, 2], "v": [2.0, 2.0]})
    out = tables.side_by_side(ours, thesis, keys=["k"], columns=["v"], how="inner")
    assert out.v_dev.tolist() == pytest.approx([-0.5, 0.0])
    with pytest.raises(KeyError, match="thesis_df lacks"):
        tables.side_by_side(ours, thesis.drop(columns="v"), keys=["k"], columns=["v"])


def test_describe_constants():
    text = tables.describe_constants(pd.DataFrame({"problem": ["poisson"] * 2, "rtol": [1e-6, 1e-6],
                                                   "rho": [1.0, 10.0]}))
    assert text == "problem=poisson, rtol=1e-06"


def test_fit_log_squared_exact():
    x = np.array([2, 4, 8, 16, 32, 64])
    c, r2 = plots.fit_log_squared(x, 0.37 * (1 + np.log(x)) ** 2)
    assert c == pytest.approx(0.37, rel=1e-12) and r2 == pytest.approx(1.0, abs=1e-12)
    # non-finite points are ignored; one point gives C but no R^2
    c, r2 = plots.fit_log_squared([4, 8, 16], [0.5 * (1 + math.log(4)) ** 2, float("nan"), None])
    assert c == pytest.approx(0.5) and math.isnan(r2)
    assert all(math.isnan(v) for v in plots.fit_log_squared([], []))


def test_fit_linear_exact():
    slope, intercept, r2 = plots.fit_linear([1, 2, 3, 4], [5.5, 8, 10.5, 13])
    assert (slope, intercept, r2) == pytest.approx((2.5, 3.0, 1.0))
    assert all(math.isnan(v) for v in plots.fit_linear([1, 1], [2, 3]))


def test_fit_log_squared_affine_and_log_linear_exact():
    x = [2, 4, 8, 16, 32, 64, 128]
    g = [(1 + math.log(v)) ** 2 for v in x]
    c1, c2, r2 = plots.fit_log_squared_affine(x, [1.5 + 0.6 * v for v in g])
    assert (c1, c2, r2) == pytest.approx((1.5, 0.6, 1.0))
    a, b, r2 = plots.fit_log_linear(x, [7 + 2 * math.log(v) for v in x])
    assert (a, b, r2) == pytest.approx((7.0, 2.0, 1.0))
    assert all(math.isnan(v) for v in plots.fit_log_squared_affine([4], [1.0]))
    with pytest.raises(ValueError):
        plots.fit_log_linear([0, 1], [1, 2])


def test_plot_writes_png(tmp_path):
    df = runs()
    out = tmp_path / "fig" / "cond.png"
    fits = plots.plot_cond_vs_Hh(df, out, methods=["feti", "fetidp"])
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    c, r2 = fits[("feti", 2)]
    assert c == pytest.approx(2.0, rel=1e-4) and r2 == pytest.approx(1.0, abs=1e-6)
    assert set(fits) == {("feti", 2), ("feti", 4), ("fetidp", 2), ("fetidp", 4)}
    assert math.isnan(fits[("feti", 4)][0])          # its H/h = 8 run did not converge: one point, no fit


def test_a_run_that_did_not_converge_is_not_fitted(tmp_path):
    """A review (2026-11-28): a run stopped at maxiter was plotted and fitted like the others. It is drawn open
    and left out of the fit: the fit of the converged runs is exact."""
    rows = [{"method": "feti", "subdomains": 2, "elements": m, "cond": 1.5 + 0.6 * (1 + math.log(m)) ** 2,
             "converged": True} for m in (2, 4, 8)]
    rows.append({"method": "feti", "subdomains": 2, "elements": 16, "cond": 1e4, "converged": False})
    fits = plots.plot_cond_vs_Hh(pd.DataFrame(rows), tmp_path / "c.png", methods=["feti"])
    assert fits[("feti", 2)] == pytest.approx((0.6, 1.0))


# --- the pipeline's configuration schema -------------------------------------------------

def validate(config):
    """The workflow's validation: the schema with the option lists of ddsolve.options injected."""
    from ddstudies.workflow import validate as workflow_validate

    return workflow_validate(config, SCHEMA)


@pytest.mark.parametrize("name", ["poisson.yaml", "table_4.yaml", "table_5_6.yaml"])
def test_shipped_configs_validate(name):
    validate(yaml.safe_load((ROOT / "config" / name).read_text()))


def test_schema_fills_defaults():
    config = validate({"kind": "grid", "study": "s", "methods": ["bddc"], "subdomains": [2], "elements": [4]})
    assert config["problem"] == "poisson" and config["rtol"] == 1e-6 and config["cond"] is True
    assert config["scaling"] == "rho" and config["maxiter"] == 1000


@pytest.mark.parametrize("change", [
    {"methods": ["feti", "newton"]},        # unknown method
    {"subdomains": [2, -4]},                # negative count
    {"elements": [1]},                      # below the minimum
    {"rtol": "1e-6x"},                      # a string that is no number
    {"maxiter": 0},
    {"rho": "stripes:3"},
    {"study": "../escape"},
    {"solver": "fetidp"},                   # unknown key
    {"methods": []},
    {"methods": ["feti-feti"]},             # a multibody method for the poisson problem
    {"contacts": ["full"]},                 # multibody only
    {"bodies": 0},
])
def test_schema_rejects_bad_config(change):
    from ddstudies.workflow import ConfigError

    config = {"kind": "grid", "study": "s", "methods": ["feti"], "subdomains": [2], "elements": [4], **change}
    with pytest.raises(ConfigError):
        validate(config)


def test_numbers_read_as_strings_become_numbers():
    """YAML 1.1 reads 1e-6 (no dot) as a string, and Snakemake's --config list items are strings: where the
    schema wants a number, the string is read as one (it was refused)."""
    config = {"kind": "grid", "study": "s", "methods": ["feti"], "subdomains": ["2"], "elements": [4], "rtol": "1e-6"}
    validate(config)
    assert config["rtol"] == 1e-6 and config["subdomains"] == [2]


def test_label_presets_splits_the_rule_sets():
    """A grid study with presets [default, thesis] has two runs per case and method: the table refused them
    (ValueError: several runs for the same case) and the plot fitted both as one; each pair is now a method."""
    from ddstudies.report.tables import condition_table, label_presets

    df = pd.DataFrame({"method": ["fetidp", "fetidp", "feti", "feti"], "subdomains": [2, 2, 2, 2],
                       "elements": [4, 4, 4, 4], "preset": ["default", "thesis", "default", "thesis"],
                       "cond": [1.2, 1.3, 1.6, 1.7], "iterations": [3, 4, 5, 6]})
    with pytest.raises(ValueError, match="several runs for the same case"):
        condition_table(df, methods=["fetidp", "feti"])
    labelled, methods = label_presets(df, ["fetidp", "feti"])
    assert methods == ["fetidp [default]", "fetidp [thesis]", "feti [default]", "feti [thesis]"]
    table = condition_table(labelled, methods=methods)
    assert table.loc[(2, 4), ("feti [thesis]", "iterations")] == 6
    assert table.loc[(2, 4), ("fetidp [default]", "cond")] == pytest.approx(1.2)
    one = df[df["preset"] == "default"]
    same, names = label_presets(one, ["fetidp", "feti"])
    assert same is one and names == ["fetidp", "feti"]


def test_a_study_of_one_other_preset_names_it_and_its_reports_run():
    """preset: thesis alone: the report jobs failed after every solve ("one_rule_set: no run of rule set
    'default'"), and the tables looked like the default's (sixth review)."""
    import pandas as pd

    from ddstudies.report.rule_sets import by_rule_set, chosen_rule_set, one_rule_set
    from ddstudies.report.tables import label_presets

    df = pd.DataFrame({"method": ["feti", "feti"], "subdomains": [2, 2], "elements": [2, 4],
                       "preset": ["thesis", "thesis"], "cond": [1.2, 1.6]})
    assert chosen_rule_set(df) == "thesis" and len(one_rule_set(df)) == 2
    table = by_rule_set(df, lambda runs: runs.set_index("elements")[["cond"]])
    assert "rule set 'thesis'" in table.attrs["notes"]["Rule sets:"]
    labelled, methods = label_presets(df, ["feti"])
    assert methods == ["feti [thesis]"] and set(labelled["method"]) == {"feti [thesis]"}
    default = df.drop(columns="preset")
    assert label_presets(default, ["feti"])[1] == ["feti"]
    assert "notes" not in by_rule_set(default, lambda runs: runs.set_index("elements")[["cond"]]).attrs
    both = pd.concat([df, df.assign(preset="other")])
    with pytest.raises(ValueError, match="no run of rule set 'default'"):
        one_rule_set(both)


def test_a_two_point_fit_shows_no_r2():
    """A two-parameter fit through two points has R^2 = 1 by construction; the legends showed "R^2=1.000" as if it
    measured the fit (a review, 2026-11-28)."""
    assert plots._r2_text(1.0, 2) == "exact, 2 points"
    assert plots._r2_text(0.98765, 3) == "$R^2$=0.988"
    assert plots._r2_text(float("nan"), 1) == "no fit, 1 point"


def test_r2_is_shown_the_same_way_everywhere():
    """The unstructured report's exponent table and the scaling report showed R^2 1.000 for two sizes while the
    cond-law tables said "exact" (a review); every report now uses ddstudies.report.fits.r2_text."""
    from ddstudies.report.fits import r2_text

    assert r2_text(1.0, 2) == "exact, 2 points" and r2_text(1.0, 2, n_params=1, spec=".2f") == "1.00"
    assert r2_text(0.5, 1) == "no fit, 1 point" and r2_text(float("nan"), 4) == "n/a"
    assert r2_text(0.91234, 3, spec=".4f", label="R^2 = ") == "R^2 = 0.9123"
