"""ddstudies.bench.cond_law (cond on METIS partitions with fitted laws) and
ddstudies.report.unstructured_contact (one unstructured contact solution with its partition)."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from ddstudies.bench.cond_law import (CondCase, case_spec, cond_cases, cond_law_markdown, cond_law_summary,
                                      fit_line, fit_log_law, fit_parts, plot_cond_law, require_points,
                                      sweep_points)

LAW = {"methods": ["fetidp", "bddc"], "primals": ["vertices"],
       "fixed_Hh": {"maxh": 0.1, "refine": [0, 1, 2], "parts": [2, 8, 32]},
       "fixed_P": {"maxh": 0.1, "refine": [0, 1, 2], "parts": 8}}


def test_log_law_recovers_c_and_the_exponent_two():
    h = np.array([4.0, 8.0, 16.0, 32.0, 64.0])
    fit = fit_log_law(h, 0.3 * (1 + np.log(h)) ** 2)
    assert fit.C == pytest.approx(0.3, rel=1e-12) and fit.r2 == pytest.approx(1.0, abs=1e-12)
    assert fit.exponent == pytest.approx(2.0, rel=1e-10) and fit.exponent_c == pytest.approx(0.3, rel=1e-10)
    assert fit.offset.a == pytest.approx(0.0, abs=1e-10) and fit.offset.b == pytest.approx(0.3, rel=1e-10)


def test_log_law_with_an_offset():
    h = np.array([4.0, 8.0, 16.0, 32.0])
    x = 1 + np.log(h)
    fit = fit_log_law(h, 1.5 + 0.1 * x ** 2)
    assert fit.offset.a == pytest.approx(1.5, rel=1e-10) and fit.offset.b == pytest.approx(0.1, rel=1e-10)
    assert fit.offset.r2 == pytest.approx(1.0, abs=1e-12)
    assert fit.r2 < 0.99 and fit.exponent < 2.0      # the offset makes the pure power law fit worse
    with pytest.raises(ValueError, match="2 distinct"):
        fit_log_law([8.0, 8.0], [2.0, 2.1])


def test_parts_fit_and_last_step():
    P = np.array([4, 16, 64, 256])
    rows = pd.DataFrame({"parts": P, "cond": 2.0 + 0.25 * np.log(P), "iterations": [10, 12, 13, 13],
                         "H_over_h": [16.0, 16.2, 16.1, 16.3]})
    fit = fit_parts(rows.iloc[::-1])        # order does not matter
    assert fit.cond.a == pytest.approx(2.0) and fit.cond.b == pytest.approx(0.25) and fit.cond.r2 == pytest.approx(1)
    assert fit.last_step == pytest.approx((2 + 0.25 * math.log(256)) / (2 + 0.25 * math.log(64)))
    assert fit.iterations_ratio == pytest.approx(1.3) and fit.parts == (4, 256) and fit.h_ratio == (16.0, 16.3)
    limit = fit_parts(rows.assign(cond=4.0 - 2.0 / np.sqrt(P))).limit     # levels off at 4
    assert limit.a == pytest.approx(4.0) and limit.b == pytest.approx(-2.0) and limit.r2 == pytest.approx(1.0)
    line = fit_line([1, 2, 3], [1, 3, 5])
    assert (line.a, line.b, line.n_points) == (pytest.approx(-1), pytest.approx(2), 3)


def test_cases_shared_by_both_sweeps_run_once():
    cases = cond_cases(LAW)
    assert len(cases) == 2 * (3 + 3 - 1)          # (0.1, r1, P8) is in both sweeps
    assert CondCase(0.1, 1, 8, "fetidp").stem == "h0.1_r1_P8"
    assert CondCase(0.1, 1, 8, "bddc", "vertices+edges").stem == "h0.1_r1_P8_vertices-edges"
    assert sweep_points(LAW["fixed_P"]) == [(0.1, 0, 8), (0.1, 1, 8), (0.1, 2, 8)]
    with pytest.raises(ValueError, match="2 values for 3"):
        sweep_points({"maxh": 0.1, "refine": [0, 1, 2], "parts": [2, 4]})
    with pytest.raises(ValueError, match="fixed_Hh: needs at least 2 distinct parts"):
        require_points({"fixed_Hh": {"maxh": 0.1, "refine": [0, 1], "parts": [4, 4]}})


def test_case_spec_is_a_valid_problem_spec():
    from ddsolve.spec import ProblemSpec

    spec = case_spec(CondCase(0.1, 1, 8, "bddc"), rtol=1e-9)
    assert "primal" not in spec
    ps = ProblemSpec.from_mapping(spec)
    assert (ps.mesh, ps.maxh, ps.refine, ps.parts, ps.method, ps.cond, ps.rtol) == (
        "unstructured", 0.1, 1, 8, "bddc", True, 1e-9)
    edges = ProblemSpec.from_mapping(case_spec(CondCase(0.1, 1, 8, "bddc", "vertices+edges")))
    assert (edges.primal, edges.method, edges.parts) == ("vertices+edges", "bddc", 8)


def _collected() -> pd.DataFrame:
    """A collected summary (as ddstudies.aggregate.collect reads it) of every case of LAW, cond from a law."""
    rows = []
    for case in cond_cases(LAW):
        ndof = 60 * 4 ** case.refine
        h = math.sqrt(ndof / case.parts)
        rows.append({"method": case.method, "maxh": case.maxh, "refine": case.refine, "param_parts": case.parts,
                     "parts": case.parts, "primal": "vertices", "ndof": ndof, "converged": True,
                     "cond": 1.2 + 0.1 * (1 + math.log(h)) ** 2 + (0.01 if case.method == "bddc" else 0.0),
                     "iterations": 10 + case.refine})
    return pd.DataFrame(rows)


def test_summary_table_fits_and_markdown(tmp_path):
    summary = cond_law_summary(_collected(), LAW)
    table = summary["table"]
    assert len(table) == 2 * 6                     # the shared case appears in both sweeps
    shared = table[(table["refine"] == 1) & (table["parts"] == 8)]
    assert sorted(shared["sweep"]) == ["fixed_Hh", "fixed_Hh", "fixed_P", "fixed_P"]
    assert np.allclose(table["H_over_h"], np.sqrt(table["ndof"] / table["parts"]))
    fit = summary["log_fits"][("fetidp", "vertices")]
    assert fit.offset.a == pytest.approx(1.2, rel=1e-9) and fit.offset.b == pytest.approx(0.1, rel=1e-9)
    assert set(summary["parts_fits"]) == {("fetidp", "vertices"), ("bddc", "vertices")}
    text = cond_law_markdown(summary)
    assert "## H/h about fixed, P growing" in text and "## P fixed, H/h growing" in text
    assert "1.200 + 0.1000 x^2" in text and "/ sqrt(P)" in text
    fig = plot_cond_law(summary, None)
    assert len(fig.axes) == 2
    plot_cond_law(summary, tmp_path / "law.png")
    assert (tmp_path / "law.png").stat().st_size > 10_000


def test_small_sweep_solves_with_bounded_condition_numbers(tmp_path):
    """Real solves: cond >= 1, every case converged, and both methods agree (same spectrum up to 1 and 0)."""
    from ddsolve.api import solve
    from ddsolve.io.hdf5 import write_result
    from ddsolve.spec import ProblemSpec
    from ddstudies.aggregate import collect

    law = {"methods": ["fetidp", "bddc"], "fixed_Hh": {"maxh": 0.25, "refine": [0, 1], "parts": [2, 8]},
           "fixed_P": {"maxh": 0.25, "refine": [0, 1], "parts": 2}}
    paths = []
    for case in cond_cases(law):
        spec = ProblemSpec.from_mapping(case_spec(case))
        path = tmp_path / f"{case.method}_{case.stem}.h5"
        write_result(path, spec, solve(spec))
        paths.append(path)
    summary = cond_law_summary(collect(paths), law)
    table = summary["table"]
    assert table["converged"].all() and (table["cond"] >= 1.0 - 1e-8).all() and (table["cond"] < 10).all()
    pair = table.pivot_table(index=["sweep", "refine", "parts"], columns="method", values="cond")
    assert np.allclose(pair["fetidp"], pair["bddc"], rtol=0.1)
    assert set(summary["log_fits"]) == {("fetidp", "vertices"), ("bddc", "vertices")}


# --------------------------------------------------------------------------- the contact figure
def test_subdomain_boundaries():
    from ddstudies.report.unstructured_contact import subdomain_boundaries

    tris = np.array([[0, 1, 2], [1, 3, 2], [3, 4, 2]])
    assert subdomain_boundaries(tris, np.array([0, 0, 0])).shape == (0, 2)
    edges = subdomain_boundaries(tris, np.array([0, 1, 1]))
    assert edges.tolist() == [[1, 2]]
    assert sorted(map(tuple, subdomain_boundaries(tris, np.array([0, 1, 2])).tolist())) == [(1, 2), (2, 3)]


def test_contact_figure_of_a_small_case(tmp_path):
    from ddstudies.report.contact_plots import contact_line, solve_contact_case
    from ddstudies.report.unstructured_contact import mesh_solution, plot_unstructured_contact

    spec = {"problem": "contact", "mesh": "unstructured", "maxh": 0.2, "parts": 2, "method": "active-set",
            "rtol": 1e-8}
    problem, solution = solve_contact_case(spec)
    assert solution.converged and problem.kkt(solution.u, solution.lam).max <= 1e-6
    mesh = mesh_solution(problem, solution.u)
    assert mesh.triangles.shape[1] == 3 and set(np.unique(mesh.subdomain)) == {0, 1, 2, 3}
    clamp = np.asarray(problem.sub.dof_of_node) < 0          # Dirichlet nodes: u = 0
    assert clamp.any() and np.all(mesh.u[clamp] == 0.0)
    line = contact_line(problem, solution)
    assert np.all(line["active"] == (line["lam"] > 0)) and line["active"].any()
    fig = plot_unstructured_contact(problem, solution, tmp_path / "c.png", title="t")
    assert (tmp_path / "c.png").stat().st_size > 20_000 and len(fig.axes) >= 3
    with pytest.raises(ValueError, match="P1 triangles"):
        mesh_solution(solve_contact_case({"problem": "contact", "method": "active-set", "subdomains": 2,
                                          "elements": 2})[0], np.zeros(1))


def test_two_point_fits_say_exact_instead_of_r2():
    """The law tables printed R^2 = 1.00 for fits through two points (a review); they say "exact"."""
    summary = cond_law_summary(_collected(), LAW)
    text = cond_law_markdown(summary)
    assert "exact" not in text                         # LAW's sweeps have three points each
    two = {**LAW, "fixed_Hh": {**LAW["fixed_Hh"], "refine": LAW["fixed_Hh"]["refine"][:2],
                               "parts": LAW["fixed_Hh"]["parts"][:2]},
           "fixed_P": {**LAW["fixed_P"], "refine": LAW["fixed_P"]["refine"][:2]}}
    text = cond_law_markdown(cond_law_summary(_collected(), two))
    assert "exact, 2 points" in text and "| exact |" not in text
    law_rows = [line for line in text.splitlines() if "x^2 |" in line and not line.startswith("| method")]
    # the one-parameter bound C x^2 through two points still has an R^2; the two-parameter laws do not
    assert law_rows and all(line.count("exact, 2 points") == 2 for line in law_rows), law_rows
