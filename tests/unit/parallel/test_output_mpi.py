"""``--output`` under mpiexec: rank 0 alone writes the .vtu file, with the serial run's fields.

Found by a black-box review of ``mpiexec -n P ddsolve solve``: ``--output`` was refused (exit 2)
under mpiexec, while rank 0 holds (or can gather) everything the serial writer needs.
"""
from __future__ import annotations

import base64
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch import ROOT, TIMEOUT, MPI_MARKS, mpi_env, mpiexec  # noqa: E402

pytestmark = MPI_MARKS

_ARRAY = re.compile(r'<DataArray type="Float64" Name="([^"]+)"[^>]*format="binary"[^>]*>\s*([^<]*)</DataArray>')


def _fields(path: Path) -> dict[str, np.ndarray]:
    """The Float64 arrays of a .vtu written by :func:`ddsolve.io.vtk.write_vtu` (inline base64, UInt32 size)."""
    out = {}
    for name, data in _ARRAY.findall(path.read_text()):
        raw = base64.b64decode(data.strip())
        size = int(np.frombuffer(raw[:4], dtype="<u4")[0])
        out[name] = np.frombuffer(raw[4:4 + size], dtype="<f8")
    return out


@pytest.mark.parametrize("args,fields", [
    (["--method", "fetidp", "--subdomains", "4", "--elements", "6", "--rho", "checkerboard:100"], ["u"]),
    (["--problem", "multibody", "--method", "hybrid", "--bodies", "2", "--subdomains", "2", "--elements", "4",
      "--contact", "middle"], ["u"]),
    (["--problem", "contact", "--method", "active-set", "--subdomains", "3", "--elements", "6"],
     ["u", "multiplier", "gap"]),
])
def test_output_written_by_rank_0_as_serial(tmp_path, args, fields):
    serial_dir, mpi_dir = tmp_path / "serial", tmp_path / "mpi"
    serial_dir.mkdir()
    mpi_dir.mkdir()
    env = {k: v for k, v in mpi_env().items() if k not in ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "PMIX_SIZE")}
    ser = subprocess.run([sys.executable, "-m", "ddsolve", "solve", *args, "--json", "--output",
                          str(serial_dir / "u.vtu")], capture_output=True, text=True, timeout=TIMEOUT, env=env,
                         cwd=ROOT)
    assert ser.returncode == 0, ser.stderr
    proc = mpiexec(3, ["-m", "ddsolve", "solve", *args, "--json", "--output", str(mpi_dir / "u.vtu")])
    assert proc.returncode == 0, proc.stderr
    assert len(proc.stdout.strip().splitlines()) == 1 and json.loads(proc.stdout)["n_ranks"] == 3
    assert sorted(p.name for p in mpi_dir.iterdir()) == ["u.vtu"]          # one file, no temporaries left
    ref, got = _fields(serial_dir / "u.vtu"), _fields(mpi_dir / "u.vtu")
    assert sorted(got) == sorted(ref)
    assert ref["Points"].tobytes() == got["Points"].tobytes()
    for name in fields:
        assert np.linalg.norm(got[name] - ref[name]) <= 1e-10 * np.linalg.norm(ref[name]), name
        assert np.linalg.norm(ref[name]) > 0, name
