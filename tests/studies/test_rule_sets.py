"""Thesis tables with both rule sets (default and a preset), paired rows and a computed note."""
from __future__ import annotations

import pandas as pd

from ddstudies.report import rule_sets as rs
from ddstudies.report.contact_tables import TABLE_5_1_COLUMNS, contact_table
from ddstudies.report.tables import multibody_table, to_latex, to_markdown

THESIS_4_2 = pd.DataFrame({"inv_Hb": [2, 4], "Hb_over_Hs": [2, 2], "Hs_over_h": [2, 2],
                           "iter_I": [10, 12], "iter_II": [10, 11]})


def multibody_runs(thesis_iters=None):
    """Default: 2x the thesis's counts; preset "thesis": given counts (default: the thesis's in (I), +1 in (II))."""
    rows = []
    for preset in ("default", "thesis"):
        for _, t in THESIS_4_2.iterrows():
            for contact, case in (("full", "I"), ("middle", "II")):
                printed = int(t[f"iter_{case}"])
                ours = 2 * printed if preset == "default" else (
                    printed + (case == "II") if thesis_iters is None else thesis_iters)
                rows.append({"method": "hybrid", "contact": contact, "bodies": t.inv_Hb, "subdomains": t.Hb_over_Hs,
                             "elements": t.Hs_over_h, "iterations": ours, "converged": True,
                             "preset": preset if preset != "default" else ""})
    return pd.DataFrame(rows).sample(frac=1.0, random_state=2)


def test_rule_sets_listed_default_first():
    assert rs.rule_sets(pd.DataFrame({"x": [1]})) == ["default"]
    assert rs.rule_sets(pd.DataFrame({"preset": ["thesis", None, "a"]})) == ["default", "a", "thesis"]


def test_multibody_table_pairs_rows_and_says_which_is_closer():
    table = multibody_table(multibody_runs(), THESIS_4_2, method="hybrid", quantities=["iterations"])
    assert table.index.names[-1] == "rules"
    assert list(table.index) == [(2, 2, 2, "default"), (2, 2, 2, "thesis"), (4, 2, 2, "default"), (4, 2, 2, "thesis")]
    assert table.loc[(2, 2, 2, "default"), ("(I)", "iterations")] == 20
    assert table.loc[(2, 2, 2, "thesis"), ("(I)", "iterations")] == 10
    assert table.loc[(4, 2, 2, "thesis"), ("(II)", "iterations_thesis")] == 11
    note = table.attrs["notes"][rs.NOTE_MARK]
    assert "preset thesis is closer to the thesis than the defaults (closer in 4, farther in 0 of 4" in note
    assert "within 1% of the thesis: 2 (thesis) and 0 (default)" in note and "Neither rule set" not in note
    md = to_markdown(table)
    lines = [ln.split("|") for ln in md.splitlines() if ln.startswith("|")]
    assert lines[0][4].strip() == "rule set"
    assert [ln[4].strip() for ln in lines[2:]] == ["default", "thesis"] * 2
    assert md.rstrip().endswith(note)
    tex = to_latex(table)
    assert "& rule set &" in tex and "2 & 2 & 2 & thesis & 10 & 10 & +0.0\\%" in tex


def test_note_when_neither_rule_set_reproduces():
    table = multibody_table(multibody_runs(thesis_iters=40), THESIS_4_2, method="hybrid", quantities=["iterations"])
    note = table.attrs["notes"][rs.NOTE_MARK]
    assert "preset thesis is not closer to the thesis than the defaults" in note
    assert "Neither rule set reproduces a printed value within 1%; what was tried: docs/findings.md." in note


def test_single_rule_set_is_unchanged():
    df = multibody_runs()
    only = df[df["preset"] == ""]
    with_col = multibody_table(only, THESIS_4_2, method="hybrid", quantities=["iterations"])
    without = multibody_table(only.drop(columns="preset"), THESIS_4_2, method="hybrid", quantities=["iterations"])
    pd.testing.assert_frame_equal(with_col, without)
    assert rs.NOTE_MARK not in with_col.attrs["notes"]


def test_contact_table_pairs_rule_sets():
    thesis = pd.DataFrame({"N_sub": [16, 64], "inv_H": [4, 8], "H_over_h": [4, 4], "ndof_lambda": [17, 33],
                           "ndof_total": [561, 2145], "pcg_it": [5, 6], "outer_it": [2, 2],
                           "inner_it": ["16 16", "21 19"], "total_it": [32, 40]})
    rows = []
    for preset, totals in (("", [64, 80]), ("thesis", [33, 40])):
        for (n, m), total in zip([(4, 4), (8, 4)], totals):
            rows.append({"method": "active-set", "subdomains": n, "elements": m, "ndof": 2 * (n * m + 1) ** 2,
                         "nlambda": n * m + 1, "pcg_iterations": 5, "outer_iterations": 2,
                         "inner_iterations": f"{total - 1} 1", "total_iterations": total, "converged": True,
                         "preset": preset})
    table = contact_table(pd.DataFrame(rows), thesis, method="active-set", columns=TABLE_5_1_COLUMNS)
    assert [k[-1] for k in table.index] == ["default", "thesis", "default", "thesis"]
    assert table[("total it.", "ours")].tolist() == [64, 33, 80, 40]
    note = table.attrs["notes"][rs.NOTE_MARK]
    assert "preset thesis is closer to the thesis than the defaults" in note
    assert "within 1% of the thesis: " in note


def test_closer_sentence_edge_cases():
    assert rs.closer_sentence({"default": pd.DataFrame()}) == "Only one rule set ran; nothing to compare."
    t = pd.DataFrame({("a", "x_dev"): [0.5]})
    u = pd.DataFrame({("b", "x"): [1.0]})
    assert "no value to compare" in rs.closer_sentence({"default": t, "thesis": u})


def test_closer_sentence_counts_differences_below_the_printed_precision_as_ties():
    """Lanczos estimates differing in the fifth digit (|dev| 6.00% vs 6.003%) make neither rule set closer."""
    base = pd.DataFrame({("(I)", "cond_dev"): [0.0600, -0.004, 0.135]})
    near = pd.DataFrame({("(I)", "cond_dev"): [0.0600, -0.00403, 0.13499]})
    note = rs.closer_sentence({"default": base, "thesis": near})
    assert "preset thesis is as close to the thesis as the defaults (not closer) (closer in 0, farther in 0 of 3" in note
    far = pd.DataFrame({("(I)", "cond_dev"): [0.08, -0.004, 0.135]})
    assert "preset thesis is not closer to the thesis than the defaults (closer in 0, farther in 1 of 3" in \
        rs.closer_sentence({"default": base, "thesis": far})
