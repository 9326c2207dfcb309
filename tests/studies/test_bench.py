"""The work-precision harness (ddstudies.bench): peers, references, one case. No timings are checked."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddsolve.api import energy_error
from ddstudies.bench import (BackendUnavailable, RunOptions, build_problem, compute_reference, direct_solver,
                           pyamg_cg, run_case)
from ddstudies.bench.methods import METHODS, get_method, register_method
from ddstudies.bench.peers import DIRECT_SOLVERS, available_direct_solvers
from ddstudies.bench.refine import prolongation, refined_spec
from ddstudies.bench.report import plot_work_precision, summary_table
from ddstudies.bench.store import read_reference, write_case, write_reference
from ddsolve.io.hdf5 import read_result

POISSON = {"problem": "poisson", "subdomains": 3, "elements": 4, "f": "random:3", "rho": "checkerboard:10"}
MULTIBODY = {"problem": "multibody", "bodies": 2, "subdomains": 2, "elements": 3, "contact": "middle"}
#: superlu is always there; the study's default backend where MKL is installed
OPTIONS = RunOptions(maxiter=500, direct="superlu")


@pytest.fixture(scope="module")
def poisson():
    problem = build_problem(POISSON, load_cells=3)
    return problem, compute_reference(problem)


@pytest.fixture(scope="module")
def multibody():
    problem = build_problem(MULTIBODY)
    return problem, compute_reference(problem)


def _spd(n: int = 60) -> sp.csr_matrix:
    lap = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    rng = np.random.default_rng(0)
    return (sp.kron(lap, sp.identity(2)) + sp.diags(rng.uniform(0.1, 1.0, 2 * n))).tocsr()


@pytest.mark.parametrize("name", available_direct_solvers())
def test_direct_solvers_agree_with_spsolve(name):
    A = _spd()
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    expected = spla.spsolve(A.tocsc(), b)
    factor_seconds, solve = direct_solver(name, A)
    assert factor_seconds >= 0
    np.testing.assert_allclose(solve(b), expected, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(solve(-3 * b), -3 * expected, rtol=1e-10, atol=1e-12)  # reusable


def test_superlu_is_always_available_and_unknown_backend_is_rejected():
    assert "superlu" in available_direct_solvers()
    with pytest.raises(KeyError, match="unknown direct solver"):
        direct_solver("nope", _spd())


def test_missing_backend_raises_clear_error(monkeypatch):
    def missing(A, threads):
        raise BackendUnavailable("backend 'x' needs 'xpkg' (pip install xpkg)")
    monkeypatch.setitem(DIRECT_SOLVERS, "x", missing)
    with pytest.raises(BackendUnavailable, match="pip install"):
        direct_solver("x", _spd())
    assert "x" not in available_direct_solvers()


def test_pyamg_cg_reaches_tolerance():
    A = _spd(200)
    b = np.ones(A.shape[0])
    res = pyamg_cg(A, b, 1e-8)
    assert res.converged and res.iterations > 0
    assert np.linalg.norm(b - A @ res.x) <= 1e-8 * np.linalg.norm(b) * 1.0001


def test_prolongation_is_galerkin_and_reference_is_consistent(poisson):
    problem, ref = poisson
    fine = build_problem(refined_spec(problem.spec), load_cells=problem.load_cells)
    P = prolongation(problem.sub.scene, problem.sub.dof_of_node, fine.sub.scene, fine.sub.dof_of_node)
    np.testing.assert_allclose((P.T @ fine.A @ P).toarray(), problem.A.toarray(), atol=1e-12)
    np.testing.assert_allclose(P.T @ fine.f, problem.f, atol=1e-12)        # the same piecewise constant load
    assert ref.info["galerkin_defect"] < 1e-12
    assert 0 < ref.discretization_error < 1
    # Pythagoras: total^2 = discretization^2 + (algebraic error in the fine norm)^2
    v = ref.u_direct * 1.01
    alg2 = energy_error(problem.A, v, ref.u_direct) ** 2 * float(ref.u_direct @ problem.A @ ref.u_direct)
    assert ref.fine.total_error(problem.A, v) ** 2 == pytest.approx(
        ref.discretization_error ** 2 + alg2 / ref.fine.energy, rel=1e-8)


@pytest.mark.parametrize("method", ["bddc", "direct", "pyamg"])
def test_case_fields(poisson, method):
    problem, ref = poisson
    rec = run_case(problem, method, 1e-8, ref, OPTIONS, repeats=1).to_dict()
    assert rec["problem"] == "poisson" and rec["method"] == method and rec["ndof"] == problem.ndof
    assert rec["converged"] is True
    assert rec["wall_seconds"] > 0 and rec["direct_seconds"] > 0
    assert rec["time_ratio"] == pytest.approx(rec["wall_seconds"] / rec["direct_seconds"])
    assert rec["cpu_ratio"] == pytest.approx(rec["cpu_seconds"] / rec["direct_cpu_seconds"])
    assert rec["algebraic_error"] < 1e-6
    assert rec["total_error"] == pytest.approx(ref.discretization_error, rel=1e-3)
    assert rec["mem_mb"] >= 0 and rec["peak_rss_mb"] > 0
    assert rec["peer"] is METHODS[method].peer
    assert (rec["iterations"] == 0) is (method == "direct")


@pytest.mark.parametrize("method", ["feti", "fetidp"])
def test_error_decreases_with_rtol_poisson(poisson, method):
    problem, ref = poisson
    errors = [run_case(problem, method, rtol, ref, OPTIONS, repeats=1).to_dict()["algebraic_error"]
              for rtol in (1e-2, 1e-6, 1e-10)]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-8


@pytest.mark.parametrize("method", ["feti-feti", "hybrid"])
def test_error_decreases_with_rtol_multibody(multibody, method):
    problem, ref = multibody
    recs = [run_case(problem, method, rtol, ref, OPTIONS, repeats=1).to_dict() for rtol in (1e-2, 1e-6, 1e-10)]
    errors = [r["algebraic_error"] for r in recs]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-8
    assert all(r["total_error"] >= ref.discretization_error * (1 - 1e-6) for r in recs)


def test_method_registry_checks_problem_and_accepts_new_methods(poisson, monkeypatch):
    with pytest.raises(KeyError, match="does not solve"):
        get_method("feti-feti", "poisson")
    with pytest.raises(KeyError, match="unknown benchmark method"):
        get_method("nope", "poisson")
    monkeypatch.setitem(METHODS, "zero", METHODS["direct"])            # restored after the test
    from ddstudies.bench.methods import MethodRun
    register_method("zero", lambda p, rtol, opt: MethodRun(u=np.zeros(p.ndof), converged=True, iterations=0),
                    problems=("poisson",), iterative=False)
    problem, ref = poisson
    rec = run_case(problem, "zero", None, ref, OPTIONS, repeats=1).to_dict()
    assert rec["algebraic_error"] == pytest.approx(1.0)
    assert rec["total_error"] == pytest.approx(1.0)


def test_files_summary_and_plot(poisson, tmp_path):
    problem, ref = poisson
    write_reference(tmp_path / "ref.h5", problem.spec.to_dict(), ref)
    back = read_reference(tmp_path / "ref.h5")
    np.testing.assert_array_equal(back.u_direct, ref.u_direct)
    assert back.discretization_error == ref.discretization_error
    paths = []
    for method, rtol in (("bddc", 1e-2), ("bddc", 1e-6), ("direct", None)):
        rec = run_case(problem, method, rtol, back, OPTIONS, repeats=1)
        paths.append(write_case(tmp_path / f"{method}_{rtol}.h5", problem.spec.to_dict(), method, rtol, rec, 1))
    row = read_result(paths[-1])
    assert row["method"] == "direct" and math.isnan(row["rtol"]) and row["repeats"] == 1
    from ddstudies.aggregate import collect

    table = summary_table(collect(paths))
    assert list(table["method"]) == ["bddc", "bddc", "direct"]
    assert table["rtol"].iloc[0] == 1e-2
    for time in ("wall", "cpu"):
        plot_work_precision(table, tmp_path / f"wp_{time}.png", time=time)
        assert (tmp_path / f"wp_{time}.png").stat().st_size > 0


CONTACT = {"problem": "contact", "subdomains": 2, "elements": 4}


@pytest.fixture(scope="module")
def contact():
    problem = build_problem(CONTACT)
    return problem, compute_reference(problem)


def test_contact_reference_is_consistent(contact):
    problem, ref = contact
    assert problem.kind == "contact" and problem.baseline == "pdas"
    assert ref.info["galerkin_defect"] < 1e-12             # P^T K_{h/2} P = K_h body by body
    assert 0 < ref.discretization_error < 1
    assert ref.vectors["lambda"].shape == (problem.context["contact"].n_contact,)
    assert ref.vectors["lambda"].min() >= 0 and ref.vectors["lambda"].max() > 0


@pytest.mark.parametrize("method", ["active-set", "smalbe", "pdas"])
def test_contact_case_fields(contact, method):
    problem, ref = contact
    options = RunOptions(maxiter=500, direct="superlu")
    rec = run_case(problem, method, 1e-8, ref, options, repeats=1).to_dict()
    assert rec["problem"] == "contact" and rec["method"] == method and rec["converged"] is True
    assert rec["peer"] is (method == "pdas")
    assert rec["direct_seconds"] > 0 and rec["time_ratio"] == pytest.approx(rec["wall_seconds"] / rec["direct_seconds"])
    assert rec["algebraic_error"] < 1e-5 and rec["l2_error"] < 1e-5 and rec["lambda_error"] < 1e-4
    assert rec["kkt_residual"] < 1e-5
    assert rec["total_error"] == pytest.approx(ref.discretization_error, rel=1e-3)
    if method == "pdas":
        assert rec["algebraic_error"] < 1e-12 and rec["iterations"] == rec["n_factorizations"]


def test_contact_error_decreases_with_rtol_and_reference_roundtrip(contact, tmp_path):
    problem, ref = contact
    write_reference(tmp_path / "ref.h5", problem.spec.to_dict(), ref)
    back = read_reference(tmp_path / "ref.h5")
    np.testing.assert_array_equal(back.vectors["lambda"], ref.vectors["lambda"])
    errors = [run_case(problem, "active-set", rtol, back, OPTIONS, repeats=1).to_dict()["lambda_error"]
              for rtol in (1e-2, 1e-8)]
    assert errors[0] > errors[1]
