"""Command line: JSON output and one-line errors with exit status 2."""
import json
import os
import subprocess
import sys

import pytest

from ddsolve.cli import main
from ddsolve.result import SCALAR_KEYS

REQUIRED = {"problem", "method", "bodies", "subdomains", "elements", "ndof", "nlambda", "converged",
            "reason", "iterations", "cond", "lambda_min", "lambda_max", "error_vs_direct",
            "setup_seconds", "solve_seconds"}


def run_main(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_json_keys_and_values(capsys):
    code, out, err = run_main(capsys, "solve", "--method", "fetidp", "--subdomains", "3", "--elements", "4",
                              "--cond", "--check", "--json")
    assert code == 0
    data = json.loads(out)
    assert REQUIRED <= set(data) and set(SCALAR_KEYS) <= set(data)
    assert data["converged"] is True and data["ndof"] == 121 and data["nlambda"] > 0
    assert data["error_vs_direct"] < 1e-5
    assert 1.0 <= data["lambda_min"] <= data["lambda_max"] and data["cond"] >= 1.0


def test_optional_fields_are_null(capsys):
    code, out, _ = run_main(capsys, "solve", "--method", "bddc", "--json")
    data = json.loads(out)
    assert code == 0
    assert data["cond"] is None and data["lambda_min"] is None and data["error_vs_direct"] is None


def test_yaml_scene_with_flag_override(tmp_path, capsys):
    scene = tmp_path / "scene.yaml"
    scene.write_text("problem: poisson\nmethod: feti\nsubdomains: 3\nelements: 4\nrho: checkerboard:10\n")
    code, out, _ = run_main(capsys, "solve", str(scene), "--method", "bddc", "--json")
    data = json.loads(out)
    assert code == 0 and data["method"] == "bddc" and data["subdomains"] == 3


BAD = [
    (["--subdomains", "0"], "subdomains"),
    (["--subdomains", "2.5"], "subdomains"),
    (["--elements", "-3"], "elements"),
    (["--elements", "1"], "elements"),          # [2, ...]: each subdomain needs interior nodes
    (["--rho", "0"], "rho"),
    (["--rho", "-2"], "rho"),
    (["--rho", "checkerboard:-5"], "rho"),
    (["--method", "multigrid"], "method"),
    (["--problem", "heat"], "problem"),
    (["--rtol", "2"], "rtol"),
    (["--maxiter", "0"], "maxiter"),
    (["--bodies", "2"], "bodies"),              # poisson has one body
]


@pytest.mark.parametrize("flags,field", BAD)
def test_bad_input_one_line_exit_2(flags, field, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(capsys, "solve", *flags)
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"ddsolve: error: {field}:")
    assert list(tmp_path.iterdir()) == []


def test_malformed_yaml(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("method: [fetidp\nsubdomains: 3\n")
    code, _, err = run_main(capsys, "solve", str(bad))
    assert code == 2 and err.count("\n") == 1 and "malformed YAML" in err


def test_unknown_yaml_field(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("subdomain: 3\n")
    code, _, err = run_main(capsys, "solve", str(bad))
    assert code == 2 and "subdomain: unknown field" in err


def test_module_entry_point_no_traceback(tmp_path):
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    ok = subprocess.run([sys.executable, "-m", "ddsolve", "solve", "--subdomains", "2", "--json"],
                        capture_output=True, text=True, env=env, timeout=120)
    assert ok.returncode == 0 and json.loads(ok.stdout)["converged"] is True
    bad = subprocess.run([sys.executable, "-m", "ddsolve", "solve", "--method", "nope"],
                         capture_output=True, text=True, env=env, timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("value, reason", [("0", True), ("1", True), ("x", False), ("3000000000", False)])
def test_elements_below_two_states_the_range_and_its_reason(value, reason):
    """--elements 0 said "[1, ...]" and 1 "mesh too small"; the documented range is [2, ...] (a review). The reason
    (interior nodes) is given for an integer below 2 only, not for a value that is no integer in range."""
    from ddsolve import ProblemSpec
    from ddsolve.errors import InputError

    with pytest.raises(InputError) as err:
        ProblemSpec(elements=value)
    assert str(err.value).startswith("elements: must be an integer in [2, 2147483647], got ")
    assert ("interior nodes" in str(err.value)) is reason
