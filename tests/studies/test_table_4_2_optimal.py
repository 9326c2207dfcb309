"""ddstudies.optimal: the Table 4.2 evidence (optimal Krylov counts, spectra, computed finding)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.sparse.linalg import aslinearoperator

from ddstudies import optimal
from ddstudies.optimal import OptimalRow, finding, preconditioned_spectrum, read_thesis_counts, render_markdown

from conftest import ROOT  # noqa: E402

THESIS = ROOT / "config" / "thesis_tables" / "table_4_2.csv"


def row(opt, thesis, pcr=None, rule_set="default", contact="full", bodies=2):
    return OptimalRow(bodies, 2, 2, contact, 60, opt if pcr is None else pcr, opt, thesis, rule_set=rule_set)


def test_read_thesis_counts():
    counts = read_thesis_counts(THESIS)
    assert counts[(2, 2, 2, "full")] == 10 and counts[(2, 2, 4, "middle")] == 13
    assert counts[(2, 18, 2, "middle")] == 7
    assert read_thesis_counts(None) == {} and read_thesis_counts(ROOT / "no_such.csv") == {}


def test_finding_all_above_and_mixed():
    text = finding([row(16, 10), row(12, 10, pcr=13, contact="middle")])
    assert "In 2 of 2 compared cases" in text
    assert "from 1.20 to 1.60" in text
    assert "PCR attains the optimal count in 1 of 2 cases (at most 1 iteration above it)" in text
    assert "no Krylov method with (4.11)" in text
    mixed = finding([row(16, 10), row(9, 10)])
    assert "In 1 of 2" in mixed and "in those cases only" in mixed
    reachable = finding([row(9, 10)])
    assert "reachable by an optimal Krylov method in every compared case" in reachable
    assert "nothing to compare" in finding([row(9, None)])


def test_render_both_rule_sets_names_each():
    rows = [row(16, 10), row(14, 10, rule_set="thesis")]
    md = render_markdown(rows)
    lines = [ln for ln in md.splitlines() if ln.startswith("| 2 |")]
    assert len(lines) == 2
    assert "| default |" in lines[0] and "| +6 |" in lines[0]
    assert "| thesis |" in lines[1] and "| +4 |" in lines[1]
    assert "rule sets default, thesis" in md
    assert md.rstrip().endswith(finding(rows).rstrip())


def test_preconditioned_spectrum_known():
    # M = diag(1, 1, 0) (semidefinite), A = diag(2, -3, 5): M A on range(M) has eigenvalues -3, 2
    A = aslinearoperator(np.diag([2.0, -3.0, 5.0]))
    M = aslinearoperator(np.diag([1.0, 1.0, 0.0]))
    np.testing.assert_allclose(preconditioned_spectrum(A, M, 3), [-3.0, 2.0], atol=1e-12)
    # non-diagonal: M = B^{-1} with B SPD -> eigenvalues of B^{-1} A (generalised problem)
    rng = np.random.default_rng(0)
    Q = rng.standard_normal((6, 6))
    B = Q @ Q.T + 6 * np.eye(6)
    Asym = rng.standard_normal((6, 6))
    Asym = Asym + Asym.T
    from scipy.linalg import eigh
    ref = eigh(Asym, B, eigvals_only=True)
    got = preconditioned_spectrum(aslinearoperator(Asym), aslinearoperator(np.linalg.inv(B)), 6)
    np.testing.assert_allclose(np.sort(got), np.sort(ref), rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError):
        preconditioned_spectrum(A, M, optimal.DENSE_LIMIT + 1)


def test_hybrid_row_small_case():
    r = optimal.hybrid_optimal_row(2, 2, 2, "middle", thesis=10)
    assert r.optimal is not None and r.optimal <= r.pcr
    assert r.neg_min <= r.neg_max < 0 < r.pos_min <= r.pos_max
    # BDDC block: the positive part starts at 1 (the lower bound of the BDDC preconditioned operator)
    assert r.pos_min == pytest.approx(1.0, abs=1e-8)


def test_hybrid_row_thesis_preset():
    """The thesis preset's hybrid keywords include s_ol_fallback=False, which HybridSolver.solve does not
    take: the study's rule table_4_2_optimal failed with a TypeError for every config with the thesis
    rule set (a review of the reports, 2026-11-27)."""
    thesis = optimal.hybrid_optimal_row(2, 2, 2, "full", preset="thesis")
    default = optimal.hybrid_optimal_row(2, 2, 2, "full")
    assert thesis.rule_set == "thesis" and default.rule_set == "default"
    assert (thesis.pcr, thesis.optimal) == (default.pcr, default.optimal) == (16, 16)   # the same rules here


def test_main_writes_report_and_json(tmp_path):
    out = tmp_path / "r" / "t.md"
    assert optimal.main(["--case", "2,2,2", "--case", "99,99,99", "--contacts", "middle",
                         "--thesis", str(THESIS), "--out", str(out)]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())
    assert len(rows) == 1 and rows[0]["thesis"] == 10 and rows[0]["bodies"] == 2   # (99,99,99) too large: skipped
    text = out.read_text()
    assert "| 2 | 2 | 2 | II | default |" in text and finding([OptimalRow(**rows[0])]) in text


def test_finding_counts_a_case_once_where_the_rule_sets_agree():
    rows = [OptimalRow(2, 2, 2, "full", 66, 16, 16, 10, -1.0, -0.5, 1.0, 2.0, rule_set=rs)
            for rs in ("default", "thesis")]
    text = finding(rows)
    assert text.startswith("In 1 of 1 compared cases (rule sets default, thesis and the same counts under each; "
                           "a case counted once where the rule sets agree)")
    assert "PCR attains the optimal count in 1 of 1 cases" in text
