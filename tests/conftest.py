"""Shared fixtures and helpers for the ddsolve test suite.

Layout: ``tests/unit/<subpackage>/`` tests one layer of the library each,
``tests/studies/`` the study code (package ``ddstudies``), ``tests/workflow/``
the Snakemake workflow. Markers:

* ``workflow``: the test runs Snakemake (every test under ``tests/workflow/`` and
  every test that calls :func:`run_snakemake` or :func:`copy_workflow`, marked here
  at collection). ``python -m pytest -m "not workflow"`` is the fast tier.
* ``slow``: a test that takes more than a few seconds on the 2-core machine.
* ``mpi``: the test launches ``mpiexec``.
"""
from __future__ import annotations

import inspect
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ddsolve import prepare
from ddsolve.dd import Substructures
from ddsolve.spec import ProblemSpec


#: The repository root (the workflow's files are copied from here).
ROOT = Path(__file__).resolve().parents[1]


def copy_workflow(dest: Path) -> Path:
    """Copy Snakefile, workflows/ and config/ to `dest`, so that runs never touch the repository."""
    shutil.copy(ROOT / "Snakefile", dest / "Snakefile")
    shutil.copytree(ROOT / "workflows", dest / "workflows", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "config", dest / "config")
    return dest


def run_snakemake(wd: Path, *args: str, check: bool = True, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m snakemake ARGS`` in `wd`, with this checkout's ddsolve and ddstudies first on the path.

    With `check`, a non-zero exit fails the test with Snakemake's output.
    """
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), str(ROOT / "studies"), env.get("PYTHONPATH")]))
    proc = subprocess.run([sys.executable, "-m", "snakemake", *args], cwd=wd, env=env,
                          capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        pytest.fail(f"snakemake {' '.join(args)} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc


def planned(proc: subprocess.CompletedProcess) -> dict[str, int]:
    """Job counts from the 'Job stats' table of a Snakemake dry run."""
    text = proc.stdout + proc.stderr
    counts = {}
    for rule in ("solve_case", "aggregate", "table", "plot_cond", "table_4", "figure_4", "all"):
        match = re.search(rf"^{rule}\s+(\d+)\s*$", text, flags=re.MULTILINE)
        counts[rule] = int(match.group(1)) if match else 0
    return counts


def _runs_snakemake(item: pytest.Item) -> bool:
    func = getattr(item, "function", None)
    if func is None:
        return False
    try:
        source = inspect.getsource(func)
    except (OSError, TypeError):
        return False
    return "run_snakemake" in source or "copy_workflow" in source or "snakemake(" in source


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test that runs Snakemake (or lives in tests/workflow/) with ``workflow``."""
    workflow_dir = ROOT / "tests" / "workflow"
    for item in items:
        path = Path(str(item.path))
        if workflow_dir in path.parents or _runs_snakemake(item):
            item.add_marker(pytest.mark.workflow)


def _side_names(center) -> str | None:
    for x, name in ((0, "wall"), (1, "gap"), (2, "far")):
        if abs(center.x - x) < 1e-9:
            return name
    return None


def two_squares(maxh: float, name_edge=_side_names):
    """NGSolve mesh of the unit squares [0,1]^2 (material "left") and [1,2]x[0,1] ("right"), sharing x = 1.

    Boundaries named by ``name_edge(edge center)`` (None: unnamed); by default "wall" (x = 0), "gap"
    (x = 1, the shared side) and "far" (x = 2).
    """
    import ngsolve as ngs
    from netgen.occ import Glue, MoveTo, OCCGeometry

    left = MoveTo(0, 0).Rectangle(1, 1).Face()
    left.faces.name = "left"
    right = MoveTo(1, 0).Rectangle(1, 1).Face()
    right.faces.name = "right"
    shape = Glue([left, right])
    for edge in shape.edges:
        name = name_edge(edge.center)
        if name:
            edge.name = name
    return ngs.Mesh(OCCGeometry(shape, dim=2).GenerateMesh(maxh=maxh))


def substructures(**fields) -> Substructures:
    """Assembled Substructures of a structured Poisson spec (fields of ProblemSpec)."""
    return prepare(ProblemSpec.from_mapping(fields)).sub


def dense(op, n: int) -> np.ndarray:
    """Columns op(e_k): only for exact spectra of tiny test cases."""
    eye = np.eye(n)
    return np.column_stack([op(eye[:, k]) for k in range(n)])


@pytest.fixture
def count_factorizations(monkeypatch):
    """A function that starts recording every subdomain factorization made from then on.

    Call it (after the setup whose factorizations are expected); it returns the list to which
    the size of each new factorization (``ddsolve.dd.local._Factor``) is appended.
    """
    from ddsolve.dd import local

    def start() -> list[int]:
        made: list[int] = []
        original = local._Factor.__init__

        def counting(self, K):
            made.append(K.shape[0])
            original(self, K)

        monkeypatch.setattr(local._Factor, "__init__", counting)
        return made

    return start


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20091)
