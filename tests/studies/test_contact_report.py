"""The contact study (Tables 5.1 / 6.1, Figure 5.2): config, dof counts, HDF5 lists, tables and plots."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from ddsolve.api import solve
from ddstudies.aggregate import collect, parse_list, write_table
from ddsolve.io.hdf5 import read_result, write_result
from ddstudies.report.contact_tables import (TABLE_5_1_COLUMNS, TABLE_6_1_COLUMNS, comparison_caption,
                                           contact_table, method_comparison, render_comparison,
                                           render_contact_table)
from ddstudies.report.tables import to_markdown
from ddsolve.spec import ProblemSpec

from conftest import ROOT  # noqa: E402
THESIS = ROOT / "config" / "thesis_tables"


@pytest.fixture(scope="module")
def thesis() -> dict[str, pd.DataFrame]:
    return {"active-set": pd.read_csv(THESIS / "table_5_1.csv"), "smalbe": pd.read_csv(THESIS / "table_6_1.csv")}


@pytest.fixture(scope="module")
def summary(tmp_path_factory) -> Path:
    """Both methods on the two smallest grids of the study, through HDF5 and the summary CSV."""
    tmp = tmp_path_factory.mktemp("contact")
    paths = []
    for method in ("active-set", "smalbe"):
        for n, m in ((4, 4), (4, 8)):
            spec = ProblemSpec.from_mapping({"problem": "contact", "method": method, "subdomains": n,
                                             "elements": m})
            paths.append(write_result(tmp / method / f"Ns{n}_m{m}.h5", spec, solve(spec)))
    return write_table(collect(paths), tmp / "summary.csv")


def merged_config(name: str) -> dict:
    """A single-study config as the workflow sees it (the schema fills in the defaults)."""
    return yaml.safe_load((ROOT / "config" / f"{name}.yaml").read_text())


def test_config_validates_and_rejects_poisson_methods():
    from ddstudies.workflow import validate  # the schema with ddsolve.options injected, as the workflow loads it

    schema = ROOT / "workflows" / "schemas" / "config.schema.yaml"
    config = merged_config("table_5_6")
    validate(config, schema)
    assert config["problem"] == "contact" and config["f"] == "dostal" and config["rtol"] == 1e-5
    assert len(config["subdomains"]) * len(config["elements"]) == 25
    assert config["methods"] == ["active-set", "smalbe"]
    for bad in ({"methods": ["fetidp"]}, {"f": "dostal:x"}, {"contacts": ["full"]}):
        with pytest.raises(Exception):
            validate({**config, **bad}, schema)
    with pytest.raises(Exception):  # contact methods stay out of the poisson studies
        validate({**merged_config("poisson"), "methods": ["smalbe"]}, schema)


def test_dof_counts_match_thesis(summary, thesis):
    df = pd.read_csv(summary)
    for method, t in thesis.items():
        ours = df[df["method"] == method].merge(t, left_on=["subdomains", "elements"],
                                                right_on=["inv_H", "H_over_h"])
        assert len(ours) == 2
        assert ours["ndof"].tolist() == ours["ndof_total"].tolist()
        assert ours["nlambda"].tolist() == ours["ndof_lambda"].tolist()
        assert ours["converged"].all()


def test_inner_iteration_lists_survive_hdf5_and_csv(summary):
    df = pd.read_csv(summary)
    for path, cell, outer, total in zip(df["file"], df["inner_iterations"], df["outer_iterations"],
                                        df["total_iterations"]):
        stored = read_result(path)["inner_iterations"]
        assert isinstance(stored, list) and stored == parse_list(cell)
        assert len(stored) == outer and sum(stored) == total


def test_tables_render_beside_the_thesis(summary, thesis):
    df = pd.read_csv(summary)
    table = contact_table(df, thesis["active-set"], method="active-set", columns=TABLE_5_1_COLUMNS)
    assert list(table.index) == [("16(4)", 4), ("16(4)", 8)]
    assert table[("N_dof(total)", "dev")].tolist() == [0.0, 0.0]
    assert table[("inner it.", "thesis")].tolist() == ["16 16", "21 19"]
    md, tex = render_contact_table(df, thesis["active-set"], "table_5_1")
    assert md.startswith("# Table 5.1") and "PCG it. thesis" in md and "16 16" in md
    assert r"$N_{sub}(1/H)$" in tex and r"\toprule" in tex
    # the label of lambda in math mode, after the escapes of to_latex (a review: after λ became $\lambda$
    # the replacement missed it), and nothing outside ASCII for pdflatex
    assert r"$N_{dof}(\lambda)$" in tex and tex.isascii()
    md6, _ = render_contact_table(df, thesis["smalbe"], "table_6_1")
    assert "PCG it." not in md6 and "24 6 5 6" in md6
    md_c, tex_c, comp, caption = render_comparison(df, thesis)
    assert caption in md_c and caption.endswith(".") and "wall time [s]" in tex_c
    assert comp[("total it.", "active set printed")].tolist() == [32, 40]


def synthetic(totals_a: list[int], totals_s: list[int]) -> pd.DataFrame:
    grids = [(4, 4), (4, 8), (8, 4), (8, 8)]
    rows = []
    for method, totals in (("active-set", totals_a), ("smalbe", totals_s)):
        for (n, m), total in zip(grids, totals):
            rows.append({"method": method, "subdomains": n, "elements": m, "ndof": 2 * (n * m + 1) ** 2,
                         "nlambda": n * m + 1, "pcg_iterations": 5, "outer_iterations": 2,
                         "inner_iterations": f"{total - 1} 1", "total_iterations": total,
                         "converged": total < 100, "setup_seconds": 0.5, "solve_seconds": 0.1 * total})
    return pd.DataFrame(rows)


def test_comparison_caption_is_computed():
    fewer = method_comparison(synthetic([10, 20, 20, 30], [40, 50, 50, 60]))
    assert "(N_dof(total) >= 2178, 3 of 4 grids)? ours: yes (70 vs 160 summed; fewer on 3 of 3 grids)" in comparison_caption(fewer)
    more = method_comparison(synthetic([10, 20, 90, 99], [40, 50, 50, 60]))
    assert "ours: no" in comparison_caption(more)
    not_converged = contact_table(synthetic([10, 20, 20, 130], [1, 1, 1, 1]), method="active-set",
                                  columns=TABLE_5_1_COLUMNS)
    assert "130*" in to_markdown(not_converged)
    assert ("total it.", "thesis") not in contact_table(synthetic([1] * 4, [1] * 4), method="smalbe",
                                                        columns=TABLE_6_1_COLUMNS).columns


def test_comparison_uses_one_rule_set_of_a_presets_sweep():
    """With runs of two presets per grid the comparison shows the default's only and names it."""
    default = synthetic([10, 20, 20, 30], [40, 50, 50, 60]).assign(preset="default")
    literal = synthetic([11, 22, 23, 35], [41, 52, 55, 66]).assign(preset="thesis")
    md, _, table, caption = render_comparison(pd.concat([default, literal]), {})
    assert table.equals(method_comparison(default.drop(columns="preset")))
    assert "Rule set: default (the runs of the other rule sets of the study, thesis, are in" in md
    assert "Rule set:" not in render_comparison(default, {})[0]
    both = contact_table(pd.concat([default, literal]), method="active-set", columns=TABLE_5_1_COLUMNS)
    assert both.index.get_level_values("rules").tolist() == ["default", "thesis"] * 4
    assert both[("total it.", "ours")].tolist() == [10, 11, 20, 22, 20, 23, 30, 35]
    # a study that ran the thesis preset only shows its runs and says so (the report job failed after the solves)
    md_literal, _, table_literal, _ = render_comparison(literal, {})
    assert "Rule set: thesis, the only one this study ran." in md_literal
    assert table_literal.equals(method_comparison(literal.drop(columns="preset")))


def test_plots_write_files(tmp_path):
    from ddstudies.report.contact_plots import (contact_line, membrane_surfaces, plot_contact_line,
                                              plot_membranes, plot_method_comparison, solve_contact_case)

    problem, solution = solve_contact_case({"problem": "contact", "method": "active-set", "subdomains": 2,
                                            "elements": 4})
    surfaces = membrane_surfaces(problem, solution.u)
    assert [s.body for s in surfaces] == [0, 1] and surfaces[0].triangles.shape == (2 * 64, 3)
    assert np.all(surfaces[0].u[surfaces[0].x == 0.0] == 0.0)  # clamped edge of Omega^1
    line = contact_line(problem, solution)
    assert len(line) == 9 and line["y"].is_monotonic_increasing
    assert (line["gap"] >= -1e-6).all() and line["active"].any() and (line["lam"] >= 0).all()
    outputs = [plot_membranes(surfaces, tmp_path / "surface.png", views=((25.0, -60.0),)),
               plot_contact_line(line, tmp_path / "contact.png"),
               plot_method_comparison(method_comparison(synthetic([10, 20, 20, 30], [40, 50, 50, 60])),
                                      tmp_path / "comparison.png", caption="caption")]
    for path in outputs:
        assert path.stat().st_size > 10_000


def test_dry_run_plans_the_contact_study(tmp_path):
    """100 solves (25 grids x 2 methods x 2 presets), one summary, both tables, the comparison and
    Figure 5.2; nothing runs."""
    import re

    from conftest import copy_workflow, run_snakemake

    pytest.importorskip("snakemake")
    proc = run_snakemake(copy_workflow(tmp_path), "-n", "--cores", "1", "--configfile", "config/table_5_6.yaml")
    text = proc.stdout + proc.stderr
    counts = {rule: int(n) for rule, n in re.findall(r"^(\w+)\s+(\d+)\s*$", text, flags=re.MULTILINE)}
    assert counts == {"solve_case": 100, "aggregate": 1, "contact_table": 2, "contact_comparison": 1,
                      "figure_5_2": 1, "contact_work_precision": 1, "all": 1, "total": 107}
    assert "results/table_5_6/smalbe/Ns20_m20.h5" in text and "results/table_5_6/smalbe/Ns20_m20_thesis.h5" in text


def test_comparison_marks_and_leaves_out_runs_that_did_not_converge():
    """A run that did not converge was compared as if valid: its count (1000) unmarked in the table and summed
    into the caption's verdict (a review). Now it is marked (*, or ‡ when rejected by the checks) and its grid
    is left out of the verdict, which says so."""
    runs = synthetic([10, 20, 20, 30], [40, 50, 50, 60])
    bad = (runs["method"] == "active-set") & (runs["subdomains"] == 8) & (runs["elements"] == 8)
    runs.loc[bad, ["total_iterations", "converged"]] = [1000, False]
    runs["reason"] = ""
    rejected = (runs["method"] == "smalbe") & (runs["subdomains"] == 4) & (runs["elements"] == 8)
    runs.loc[rejected, ["converged", "reason"]] = [False, "not accepted: stopping rule met (...)"]
    table = method_comparison(runs)
    text = to_markdown(table)
    assert "1000*" in text and "50‡" in text
    caption = comparison_caption(table)
    assert "ours: yes (20 vs 50 summed; fewer on 1 of 1 grids; 2 grid(s) left out: a run did not converge" in caption
