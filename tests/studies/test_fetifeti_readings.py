"""ddstudies.fetifeti_readings: exact FETI-FETI spectra under the readings of Table 4.1."""
from __future__ import annotations

import numpy as np
import pytest

from ddstudies import fetifeti_readings as fr

from conftest import ROOT  # noqa: E402


def test_non_redundant_keeps_a_spanning_forest():
    # 4 copies at one location, fully redundant (6 pairs), and one ordinary pair
    pairs = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3], [4, 5]])
    active = np.ones(7, dtype=bool)
    keep = fr.non_redundant(pairs, active)
    assert keep.tolist() == [True, True, True, False, False, False, True]
    active[0] = False
    keep = fr.non_redundant(pairs, active)
    assert keep.sum() == 4 and not keep[0]


@pytest.fixture(scope="module")
def case_222():
    from threadpoolctl import threadpool_limits

    from ddsolve.multibody import GlobalInterface
    from ddsolve.multibody.fetifeti import FetiFetiSolver
    from ddsolve.prepared import prepare
    from ddsolve.spec import ProblemSpec

    spec = ProblemSpec.from_mapping(dict(problem="multibody", method="feti-feti", bodies=2, subdomains=2,
                                         elements=2, f="random:0"))
    with threadpool_limits(1, "blas"):
        prep = prepare(spec)
        gi = GlobalInterface(prep.sub)
        return FetiFetiSolver(prep.sub, gi), gi


@pytest.mark.parametrize("contact", ["full", "middle"])
def test_default_reading_bounds_the_lanczos_estimate(case_222, contact):
    """The exact spectrum contains PCG's Lanczos estimates (Ritz values lie inside it)."""
    solver, gi = case_222
    active = gi.contact_mask(contact)
    n, lo, hi = fr.exact_condition(fr.DualBlocks(solver, active))
    out = solver.solve(active, rtol=1e-10, maxiter=200, cond=True)
    assert lo <= out.krylov.lambda_min * (1 + 1e-8)
    assert out.krylov.lambda_max <= hi * (1 + 1e-8)
    # PCG to 1e-10 on a dual space of this size has found the extremes
    assert out.krylov.lambda_max == pytest.approx(hi, rel=1e-6)
    assert lo >= 1 - 1e-8                              # FETI-DP-type lower bound 1


def test_readings_rows_and_summary(case_222, tmp_path):
    thesis = fr.read_thesis_cond(ROOT / "config" / "thesis_tables" / "table_4_1.csv")
    assert thesis[(2, 2, 2, "full")] == pytest.approx(2.5536)
    rows = fr.rows_for([(2, 2, 2), (50, 50, 50)], ["full"], thesis,
                       readings=[("weighted", "all", "full"), ("orthogonal", "pair", "tree")])
    assert len(rows) == 2 and rows[0].projection == "weighted"   # (50,50,50) skipped (too large)
    assert rows[1].n_dual < rows[0].n_dual                        # tree drops redundant multipliers
    text = fr.summary(rows)
    best = min(rows, key=lambda r: abs(r.cond - 2.5536))
    assert f"closest {best.cond:.4f}" in text and f"ddsolve's reading {rows[0].cond:.4f}" in text
    md = fr.render_markdown(rows)
    assert md.count("\n| 2 | 2 | 2 | I |") == 2 and text in md
    assert fr.summary([]) == "No case has a thesis value."
