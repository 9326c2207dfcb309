"""The numerical library stays free of the study dependencies (pandas, matplotlib, pyamg)."""
import json
import os
import subprocess
import sys

#: ddsolve and its numerical subpackages (everything but the studies, which are ddstudies).
NUMERICAL = ("ddsolve", "ddsolve.scene", "ddsolve.dd", "ddsolve.multibody", "ddsolve.contact", "ddsolve.krylov",
             "ddsolve.qp", "ddsolve.io", "ddsolve.io.hdf5", "ddsolve.io.joblog", "ddsolve.api", "ddsolve.prepared",
             "ddsolve.options", "ddsolve.spec", "ddsolve.cli")
STUDY_ONLY = ("pandas", "matplotlib", "pyamg")


def _loaded_after(modules, probe):
    """Which of `probe` are in sys.modules after importing `modules` in a fresh interpreter."""
    code = ("import importlib, json, sys\n"
            f"for name in {list(modules)!r}:\n"
            "    importlib.import_module(name)\n"
            f"print(json.dumps([m for m in {list(probe)!r} if m in sys.modules]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=300)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_ddsolve_imports_no_study_dependencies():
    assert _loaded_after(NUMERICAL, STUDY_ONLY) == []


def test_probe_detects_a_study_import():
    # the same probe sees pandas once the study package is imported (the check can fail)
    assert "pandas" in _loaded_after(("ddstudies.aggregate",), STUDY_ONLY)


def test_ddsolve_has_no_study_subpackages():
    from pathlib import Path

    import ddsolve
    root = Path(ddsolve.__file__).parent
    for path in ("report", "bench", "io/aggregate.py"):
        assert not (root / path).exists(), path
