"""The contact scaling study (ddstudies.bench.scaling) and the pluggable PDAS factorization. No timings are checked."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from ddstudies.bench.contact import backend_factorize
from ddstudies.bench.peers import available_direct_solvers
from ddstudies.bench.scaling import (build_contact, case_params, contact_spec, fit_exponent, plot_scaling,
                                   profile_case, run_scaling_case, scaling_summary, summary_markdown)
from ddsolve.contact import solve_contact_direct
from ddstudies.aggregate import collect
from ddsolve.io.hdf5 import write_result


@pytest.fixture(scope="module")
def small_contact():
    problem, _ = build_contact(contact_spec(4, 4))
    return problem


@pytest.mark.parametrize("backend", [b for b in ("mkl-pardiso", "superlu") if b in available_direct_solvers()])
def test_pluggable_factorization_matches_superlu(small_contact, backend):
    default = solve_contact_direct(small_contact)
    calls = []

    def factorize(A):
        calls.append(A.shape)
        return backend_factorize(backend)(A)

    plugged = solve_contact_direct(small_contact, factorize=factorize)
    assert default.converged and plugged.converged
    assert len(calls) == plugged.n_factorizations == default.n_factorizations
    np.testing.assert_array_equal(plugged.active, default.active)
    np.testing.assert_allclose(plugged.u, default.u, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(plugged.lam, default.lam, rtol=1e-9, atol=1e-12)


def test_pluggable_factorization_rejects_empty_active_set(small_contact):
    from ddsolve.contact.direct import solve_face_direct

    with pytest.raises(ValueError, match="not tied"):
        solve_face_direct(small_contact, np.zeros(small_contact.n_contact, dtype=bool),
                          factorize=backend_factorize("superlu"))


def test_fit_exponent_recovers_synthetic_power_law():
    n = np.array([1e4, 5e4, 1e5, 3e5, 1e6])
    fit = fit_exponent(n, 2e-5 * n ** 1.3)
    assert fit.exponent == pytest.approx(1.3, abs=1e-12)
    assert fit.prefactor == pytest.approx(2e-5, rel=1e-9)
    assert fit.r2 == pytest.approx(1.0) and fit.n_points == 5
    noisy = 3e-4 * n * np.exp(np.random.default_rng(0).normal(0, 0.05, n.size))
    assert fit_exponent(n, noisy).exponent == pytest.approx(1.0, abs=0.1)
    assert fit_exponent([1e3, 1e4, np.nan], [1.0, 10.0, 5.0]).n_points == 2      # non-finite pair dropped
    with pytest.raises(ValueError):
        fit_exponent([1e3, 1e3], [1.0, 2.0])


def _synthetic(ratio_small: float, ratio_large: float, power: float = 1.1) -> pd.DataFrame:
    rows = []
    for m, n in ((4, 13041), (20, 321201), (40, 1282401)):
        t_direct = 1e-5 * n ** power
        ratio = ratio_small if n < 1e6 else ratio_large
        for method, t in (("active-set", ratio * t_direct), ("pdas", t_direct)):
            rows.append({"method": method, "subdomains": 20, "elements": m, "ndof": n, "wall_seconds": t,
                         "cpu_seconds": t, "iterations": 10, "outer_iterations": 2, "converged": True,
                         "direct_backend": "mkl-pardiso", "direct_threads": 1})
    return pd.DataFrame(rows)


def test_summary_targets_and_plot(tmp_path):
    summary = scaling_summary(_synthetic(1.2, 0.8))
    assert summary["fits"]["pdas"].exponent == pytest.approx(1.1)
    assert summary["ratio_at"] == pytest.approx(1.2) and summary["ratio_largest"] == pytest.approx(0.8)
    assert [met for _, _, met in summary["targets"]] == [True, True, True]
    text = summary_markdown(summary)
    assert "| 20 | 40 | 1,282,401 |" in text and "dofs^" in text
    assert "Rule sets: every number here is from rule set 'default'" in text     # the rules named
    bad = scaling_summary(_synthetic(3.0, 3.0, power=1.3))
    assert bad["fits"]["active-set"].exponent == pytest.approx(1.3)
    assert [met for _, _, met in bad["targets"]] == [False, False, False]
    plot_scaling(_synthetic(1.2, 0.8), tmp_path / "scaling.png")
    assert (tmp_path / "scaling.png").stat().st_size > 0
    # no direct runs: "n/a", not "nan"; a time falling with the size is not a growth law that meets a target
    alone = _synthetic(1.2, 0.8)
    alone = alone[alone["method"] == "active-set"].copy()
    alone["wall_seconds"] = alone["wall_seconds"].to_numpy()[::-1]
    lonely = scaling_summary(alone)
    text = summary_markdown(lonely)
    assert "nan" not in text and "n/a (no direct run at that size)" in text and "n/a (no runs of both" in text
    assert [met for _, _, met in lonely["targets"]] == [None, None, None]
    assert "(not a growth law: sizes too small)" in text
    # two sizes fit any exponent exactly: no verdict, and no R^2 (it read "R^2 = 1.0000" and "yes"; a review)
    two = scaling_summary(_synthetic(1.2, 0.8).query("ndof < 1e6"))
    assert two["targets"][2][1:] == ("dofs^1.100 (not a growth law: 2 sizes)", None)
    assert "(exact, 2 sizes, no R^2)" in summary_markdown(two) and "R^2 = 1.0000" not in summary_markdown(two)
    assert "(R^2 = 1.0000, 3 sizes)" in summary_markdown(summary)             # three sizes: a fit with its R^2


@pytest.mark.parametrize("method", ["active-set", "pdas"])
def test_scaling_case_writes_a_result_file(tmp_path, method):
    record = run_scaling_case(2, 4, method, repeats=2, repeat_budget=0.0)
    values = record.to_dict()
    assert values["ndof"] == 2 * 9 ** 2 - 9 and values["converged"] is True
    assert values["repeats_done"] == 1                        # the budget stops after one solve
    assert values["wall_seconds"] > 0 and values["kkt_residual"] < 1e-4
    assert values["blas_threads"] == 1 and values["threads"] == 1
    path = write_result(tmp_path / f"{method}.h5", case_params(2, 4, method, rtol=1e-5, maxiter=1000, repeats=2),
                        record)
    row = collect([path]).iloc[0]
    assert row["method"] == method and row["ndof"] == values["ndof"]
    assert math.isnan(row["rtol"]) is (method == "pdas")


def test_profile_lists_functions():
    text = profile_case(2, 4, "active-set", top=5)
    assert "cProfile of active-set" in text and "tottime" in text and "ncalls" in text


def test_scaling_workflow_dry_run(tmp_path):
    """config/scaling.yaml plans one job per (method, H/h), the summary, plot and profile, and nothing else."""
    import re

    from conftest import copy_workflow, run_snakemake

    pytest.importorskip("snakemake")
    from conftest import ROOT as root
    proc = run_snakemake(copy_workflow(tmp_path), "-n", "--cores", "2", "--configfile", "config/scaling.yaml")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    text = proc.stdout + proc.stderr
    import yaml

    cfg = yaml.safe_load((root / "config" / "scaling.yaml").read_text())
    expected = len(cfg["methods"]) * len(cfg["elements"])
    assert int(re.search(r"^scaling_case\s+(\d+)\s*$", text, re.MULTILINE).group(1)) == expected
    for rule in ("scaling_summary", "scaling_plot", "scaling_profile", "all"):
        assert re.search(rf"^{rule}\s+1\s*$", text, re.MULTILINE), rule
    assert not re.search(r"^solve_case\s", text, re.MULTILINE)       # not the default study


def test_runs_that_did_not_converge_are_marked_and_left_out():
    """A non-converged active-set run (50 s at the smallest size) was fitted (dofs^2.3), compared (ratio 371)
    and judged against the targets without a mark in the Markdown report (a review)."""
    df = _synthetic(1.2, 1.2)
    bad = (df["method"] == "active-set") & (df["ndof"] == 13041)
    df.loc[bad, ["wall_seconds", "converged"]] = [50.0, False]
    summary = scaling_summary(df)
    assert summary["fits"]["active-set"].exponent == pytest.approx(1.1)        # the two converged sizes
    assert summary["fits"]["active-set"].n_points == 2
    table = summary["table"]
    assert math.isnan(table.loc[table["ndof"] == 13041, "ratio"].iloc[0])
    assert summary["ratio_at"] == pytest.approx(1.2)
    text = summary_markdown(summary)
    assert "| 20 | 4 | 13,041 | 50.000 |" in text and "10 (2)* |" in text
    assert "not converged (stopped at maxiter or by a breakdown)" in text and "left out of the fits" in text


@pytest.mark.workflow
def test_an_option_of_one_method_reruns_only_that_method(tmp_path):
    """Each scaling case's params hold only what its method reads: a new backend of the direct reference
    (pdas) reruns the pdas cases alone, a new rtol the active-set cases alone. Before, both options
    were in every case's params, so either change reran the whole study."""
    import re

    from conftest import copy_workflow, run_snakemake

    pytest.importorskip("snakemake")
    wd = copy_workflow(tmp_path)
    tiny = ("kind: scaling\nstudy: tiny\nsubdomains: 2\nelements: [2, 4]\nmethods: [active-set, smalbe, pdas]\n"
            "repeats: 1\nmaxiter: 500\n")
    (wd / "tiny.yaml").write_text(tiny)
    targets = [f"results/tiny/{method}/N2_m2.h5" for method in ("active-set", "smalbe", "pdas")]
    base = ["--cores", "1", "--configfile", "config/scaling.yaml", "tiny.yaml"]
    run_snakemake(wd, *targets, *base)          # targets first: --configfile takes every path after it

    def planned(extra: str) -> list[str]:
        (wd / "tiny.yaml").write_text(tiny + extra)
        proc = run_snakemake(wd, "-n", *targets, *base)
        return sorted(set(re.findall(r"output: (results/\S+)", proc.stdout + proc.stderr)))

    assert planned("") == []
    assert planned("direct: superlu\n") == ["results/tiny/pdas/N2_m2.h5"]
    assert planned("rtol: 1.0e-4\n") == ["results/tiny/active-set/N2_m2.h5", "results/tiny/smalbe/N2_m2.h5"]
    from ddsolve.io.hdf5 import read_params
    # each method's files record the options it read (smalbe's rtol and maxiter were lost; a review)
    assert read_params(wd / targets[1])["maxiter"] == 500 and math.isnan(read_params(wd / targets[2])["maxiter"])
