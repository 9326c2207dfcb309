"""examples/ddinverse.py runs and writes its VTK file."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("ngsolve")

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize("script, parts", [("ddinverse.py", 16), ("ddinverse_3d.py", 24)])
def test_example_ddinverse(tmp_path, script, parts):
    env = dict(os.environ, OMP_NUM_THREADS="1",
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / script), str(tmp_path / "u")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    match = re.search(r"(\d+) iterations on (\d+) parts, (\d+) dofs", proc.stdout)
    assert match and 0 < int(match.group(1)) < 60 and int(match.group(2)) >= parts
    vtu = tmp_path / "u.vtu"
    assert vtu.stat().st_size > 10_000


def test_example_contact(tmp_path):
    env = dict(os.environ, OMP_NUM_THREADS="1",
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "contact.py"), str(tmp_path / "c")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    match = re.search(r"(\d+) of (\d+) contact nodes active, KKT (\S+)", proc.stdout)
    assert match and 0 < int(match.group(1)) < int(match.group(2)) and float(match.group(3)) <= 1e-6
    assert (tmp_path / "c.vtu").stat().st_size > 10_000
