"""HDF5 result files and the aggregated CSV (ddsolve.io)."""
from __future__ import annotations

import math

import h5py
import numpy as np
import pandas as pd
import pytest

from ddsolve.io import hdf5
from ddstudies import aggregate
from ddsolve.result import SCALAR_KEYS, SolveResult
from ddsolve.spec import ProblemSpec


def make_case(method="feti", subdomains=2, elements=4, cond=3.25, converged=True, extra=None):
    """A hand-made spec and result (no solver involved)."""
    spec = ProblemSpec.from_mapping({"method": method, "subdomains": subdomains,
                                     "elements": elements, "cond": True, "check": False})
    iterations = 5
    result = SolveResult(
        problem="poisson", method=method, bodies=1, subdomains=subdomains, elements=elements,
        ndof=49, nlambda=18, converged=converged, reason="converged" if converged else "maxiter 5 reached",
        iterations=iterations, residuals=np.logspace(0, -7, iterations + 1), cond=cond,
        lambda_min=1.0 if cond is not None else None, lambda_max=cond, error_vs_direct=None,
        setup_seconds=0.25, solve_seconds=0.5, n_factorizations=4,
        u=np.arange(49.0), extra=dict(extra or {}))
    return spec, result


def tmp_leftovers(directory):
    return [p.name for p in directory.iterdir() if p.name.endswith(".tmp")]


def test_roundtrip_scalars_lists_residuals(tmp_path):
    spec, result = make_case(cond=None, extra={"inner_iterations": [16, 16, 3], "omega": 0.5,
                                               "label": "x", "gap": None})
    path = hdf5.write_result(tmp_path / "sub" / "run.h5", spec, result)
    assert path.exists() and tmp_leftovers(path.parent) == []

    flat = hdf5.read_result(path)
    # parameters (the cond *flag* is renamed because the result has a cond *estimate*)
    assert flat["method"] == "feti" and flat["subdomains"] == 2 and flat["elements"] == 4
    assert flat["param_cond"] is True and flat["check"] is False
    assert flat["rtol"] == pytest.approx(1e-6) and flat["scaling"] == "rho"
    # scalar results with their Python types; None -> NaN
    assert set(SCALAR_KEYS) <= set(flat)
    assert flat["converged"] is True and isinstance(flat["converged"], bool)
    assert flat["iterations"] == 5 and isinstance(flat["iterations"], int)
    assert flat["reason"] == "converged" and isinstance(flat["reason"], str)
    assert math.isnan(flat["cond"]) and math.isnan(flat["error_vs_direct"]) and math.isnan(flat["gap"])
    assert flat["omega"] == 0.5 and flat["label"] == "x"
    # list-valued extras as lists
    assert flat["inner_iterations"] == [16, 16, 3]
    assert "residuals" not in flat and "u" not in flat
    np.testing.assert_array_equal(hdf5.read_residuals(path), result.residuals)
    assert hdf5.read_solution(path) is None  # not stored by default

    with h5py.File(path, "r") as h5:
        assert h5.attrs["format"] == "ddsolve-result"
        assert int(h5.attrs["format_version"]) == 1
        assert isinstance(h5.attrs["ddsolve_version"], str)
        assert set(h5["params"].attrs) == set(ProblemSpec.fields())
        assert h5["result/inner_iterations"].dtype == np.int64
        assert h5["result/residuals"].dtype == np.float64
        assert np.isnan(h5["result"].attrs["cond"])


def test_params_roundtrip_checkerboard_rho(tmp_path):
    spec = ProblemSpec.from_mapping({"method": "fetidp", "rho": "checkerboard:100", "gamma": 0.5})
    _, result = make_case(method="fetidp")
    hdf5.write_result(tmp_path / "r.h5", spec, result)
    params = hdf5.read_params(tmp_path / "r.h5")
    assert params == spec.to_dict()


def test_store_solution_optional(tmp_path):
    spec, result = make_case()
    hdf5.write_result(tmp_path / "r.h5", spec, result, store_solution=True)
    np.testing.assert_array_equal(hdf5.read_solution(tmp_path / "r.h5"), result.u)


def test_list_with_none_and_empty_list(tmp_path):
    spec, result = make_case(extra={"gaps": [1.5, None], "none_yet": []})
    flat = hdf5.read_result(hdf5.write_result(tmp_path / "r.h5", spec, result))
    assert flat["gaps"][0] == 1.5 and math.isnan(flat["gaps"][1])
    assert flat["none_yet"] == []


@pytest.mark.parametrize("where", ["fsync", "replace", "create_dataset"])
def test_atomic_write_leaves_nothing_on_failure(tmp_path, monkeypatch, where):
    spec, result = make_case()
    target = tmp_path / "run.h5"

    def boom(*args, **kwargs):
        # the temporary file exists when we fail on the disk; the HDF5 file is built in memory first
        assert len(tmp_leftovers(tmp_path)) == (0 if where == "create_dataset" else 1)
        raise OSError("simulated crash")

    if where == "fsync":
        monkeypatch.setattr(hdf5.os, "fsync", boom)
    elif where == "replace":
        monkeypatch.setattr(hdf5.os, "replace", boom)
    else:
        monkeypatch.setattr(h5py.Group, "create_dataset", boom)
    with pytest.raises(OSError, match="simulated crash"):
        hdf5.write_result(target, spec, result)
    assert not target.exists()
    assert tmp_leftovers(tmp_path) == []


def test_failed_rewrite_keeps_previous_file(tmp_path, monkeypatch):
    spec, result = make_case(cond=2.0)
    target = hdf5.write_result(tmp_path / "run.h5", spec, result)
    _, other = make_case(cond=9.0)
    monkeypatch.setattr(hdf5.os, "fsync", lambda fd: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises(OSError):
        hdf5.write_result(target, spec, other)
    assert hdf5.read_result(target)["cond"] == 2.0
    assert tmp_leftovers(tmp_path) == []


def test_unstorable_values_rejected_before_writing(tmp_path):
    spec, result = make_case(extra={"ragged": [[1, 2], [3]]})
    with pytest.raises(TypeError, match="ragged"):
        hdf5.write_result(tmp_path / "r.h5", spec, result)
    assert list(tmp_path.iterdir()) == []


def test_spec_result_mismatch_rejected(tmp_path):
    spec, _ = make_case(method="feti")
    _, result = make_case(method="bddc")
    with pytest.raises(ValueError, match="method"):
        hdf5.write_result(tmp_path / "r.h5", spec, result)


def test_read_rejects_foreign_file(tmp_path):
    with h5py.File(tmp_path / "other.h5", "w") as h5:
        h5.attrs["format"] = "something-else"
    with pytest.raises(ValueError, match="not a ddsolve result"):
        hdf5.read_result(tmp_path / "other.h5")


def test_collect_and_csv_roundtrip(tmp_path):
    paths = []
    for method, elements, cond in [("feti", 4, 2.5), ("feti", 8, None), ("bddc", 4, 1.75)]:
        extra = {"inner_iterations": [3, 4]} if method == "feti" else {}
        spec, result = make_case(method=method, elements=elements, cond=cond, extra=extra)
        paths.append(hdf5.write_result(tmp_path / method / f"m{elements}.h5", spec, result))
    df = aggregate.collect(paths)
    assert len(df) == 3
    assert list(df.columns[:5]) == ["problem", "method", "bodies", "subdomains", "elements"]
    assert "param_cond" in df.columns and "cond" in df.columns and df.columns[-1] == "file"
    assert df["inner_iterations"].iloc[0] == [3, 4]

    csv = aggregate.write_table(df, tmp_path / "out" / "summary.csv")
    back = pd.read_csv(csv)
    assert len(back) == 3 and list(back.columns) == list(df.columns)
    assert back["method"].tolist() == ["feti", "feti", "bddc"]
    assert back["elements"].tolist() == [4, 8, 4]
    assert back["cond"].iloc[0] == 2.5 and math.isnan(back["cond"].iloc[1])
    assert back["converged"].tolist() == [True, True, True]
    assert back["inner_iterations"].iloc[0] == "3 4" and pd.isna(back["inner_iterations"].iloc[2])
    assert tmp_leftovers(csv.parent) == []


def test_collect_empty():
    df = aggregate.collect([])
    assert len(df) == 0
