"""What the mpiexec tests of this folder share: paths, the skip marks, the environment, the launcher."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
MPIEXEC = shutil.which("mpiexec")
try:
    import mpi4py  # noqa: F401
    HAVE_MPI4PY = True
except ImportError:         # pragma: no cover
    HAVE_MPI4PY = False

#: ``pytestmark`` of every module that launches mpiexec.
MPI_MARKS = [pytest.mark.mpi,
             pytest.mark.skipif(MPIEXEC is None or not HAVE_MPI4PY,
                                reason="mpiexec or mpi4py not installed: distributed solves cannot be launched")]
TIMEOUT = 120


def mpi_env(**extra: str) -> dict[str, str]:
    """This checkout (and this folder's case scripts) first on the path, one thread per rank."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(ROOT / "studies"), str(HERE), env.get("PYTHONPATH", "")])
    env["OMP_NUM_THREADS"] = "1"
    env.update(extra)
    return env


def mpiexec(n: int, args: list[str], **env: str) -> subprocess.CompletedProcess:
    """``mpiexec -n n python ARGS`` in the repository root."""
    return subprocess.run([MPIEXEC, "-n", str(n), sys.executable, *args], capture_output=True, text=True,
                          timeout=TIMEOUT, env=mpi_env(**env), cwd=ROOT)
