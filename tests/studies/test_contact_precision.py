"""ddstudies.contact_precision: active set vs SMALBE at matched KKT residual, per rule set."""
from __future__ import annotations

import pandas as pd
import pytest

from ddstudies import contact_precision as cp
from ddstudies import workflow


def fake(rule_set, grid, method, runs, extra=0):
    return [dict(rule_set=rule_set, subdomains=grid[0], elements=grid[1], method=method, rtol=r, total_iterations=it,
                 extra_iterations=extra, work_iterations=it + extra, polished=extra > 0 and method == "smalbe",
                 seconds=it / 100, kkt_residual=k, converged=True) for r, it, k in runs]


def frame():
    rows = []
    # default: active set cheaper at every accuracy; thesis: SMALBE cheaper
    rows += fake("default", (4, 4), "active-set", [(1e-4, 10, 1e-5), (1e-6, 14, 1e-7)])
    rows += fake("default", (4, 4), "smalbe", [(1e-4, 20, 1e-6), (1e-6, 30, 1e-8)])
    rows += fake("thesis", (4, 4), "active-set", [(1e-4, 25, 1e-5), (1e-6, 40, 1e-7)])
    rows += fake("thesis", (4, 4), "smalbe", [(1e-4, 12, 1e-6), (1e-6, 18, 1e-8)])
    return pd.DataFrame(rows, columns=cp.COLUMNS)


def test_matched_work_uses_the_cheapest_run_reaching_each_target():
    mw = cp.matched_work(frame())
    d = mw[mw["rule_set"] == "default"].set_index("target")
    # targets reached by both: 1e-5, 1e-6, 1e-7 (1e-8 only by SMALBE)
    assert sorted(d.index) == [1e-7, 1e-6, 1e-5]
    assert d.loc[1e-5, "it active-set"] == 10 and d.loc[1e-5, "it smalbe"] == 20
    assert d.loc[1e-6, "it active-set"] == 14 and d.loc[1e-6, "it smalbe"] == 20
    assert d.loc[1e-7, "it smalbe"] == 30


def test_verdict_per_rule_set_and_markdown_names_both():
    text = cp.verdict(frame())
    assert "rule set default: the active set method needs fewer iterations (total + initial PCG / polish)" in text
    assert "(38 vs 70 summed over 3 (grid, target) pairs" in text
    assert "rule set thesis: SMALBE needs fewer iterations (total + initial PCG / polish)" in text
    md = cp.render_markdown(frame())
    assert "| default | 4 | 4 | active set | 1e-04 | 10 | 0 | 10 | no |" in md
    assert "| thesis | 4 | 4 | SMALBE | 1e-06 | 18 | 0 | 18 | no |" in md
    assert md.rstrip().endswith(text)
    assert cp.verdict(pd.DataFrame(columns=cp.COLUMNS)) == "No grid has converged runs of both methods."
    df = frame()
    df.loc[(df["rule_set"] == "thesis") & (df["method"] == "smalbe") & (df["rtol"] == 1e-6), "converged"] = False
    text = cp.verdict(df)
    assert "1 of 4 runs reported not converged are left out (SMALBE 1)" in text
    # SMALBE's converged run reaches 1e-6 only: targets 1e-5, 1e-6 (active set 25 + 40, SMALBE 12 + 12)
    assert "rule set thesis: SMALBE needs fewer iterations (total + initial PCG / polish) at matched KKT residual (65 vs 24" in text


def test_the_polish_and_the_initial_pcg_count_as_work():
    """The default SMALBE's accuracy is its polish's: its PCG iterations are work too (a review: the verdict
    "active set fewer: 586 vs 587" left out 8-14 polish iterations per run)."""
    rows = fake("default", (4, 4), "active-set", [(1e-4, 10, 1e-5)], extra=3)
    rows += fake("default", (4, 4), "smalbe", [(1e-4, 9, 1e-5)], extra=12)
    df = pd.DataFrame(rows, columns=cp.COLUMNS)
    mw = cp.matched_work(df)
    assert (mw["it active-set"].item(), mw["it smalbe"].item()) == (13, 21)
    assert "the active set method needs fewer" in cp.verdict(df)
    assert "| default | 4 | 4 | SMALBE | 1e-04 | 9 | 12 | 21 | yes |" in cp.render_markdown(df)


def test_plot_and_rule_sets(tmp_path):
    png = cp.plot_work_precision(frame(), tmp_path / "wp.png")
    assert png.stat().st_size > 1000
    sets = workflow.rule_sets()
    assert sets[0] == "default" and len(sets) == len(set(sets))
    assert workflow.contact_precision_grids([2, 4, 8], [4, 8]) == ["2,4", "2,8", "4,4", "4,8", "8,4"]


@pytest.mark.slow
def test_real_grid_runs_and_reaches_kkt():
    recs = cp.run_grid(2, 4, [1e-4, 1e-8])
    df = pd.DataFrame(recs, columns=cp.COLUMNS)
    assert len(df) == 4 and df["converged"].all()
    for meth in cp.METHODS:
        g = df[df["method"] == meth].set_index("rtol")
        # a tighter tolerance never costs fewer iterations and reaches a KKT residual below 1e-6
        assert g.loc[1e-8, "total_iterations"] >= g.loc[1e-4, "total_iterations"]
        assert g.loc[1e-8, "kkt_residual"] < 1e-6
