"""A writer terminated by SIGTERM or SIGHUP leaves no temporary file (ddsolve.io.cleanup).

A review stopped ``ddsolve solve --output k.vtu`` with ``timeout -s TERM`` (serial and under mpiexec)
and found the complete temporary file ``.k.<pid>.<hex>.tmp.vtu`` beside the target.
"""
from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

CHILD = textwrap.dedent("""
    import os, signal, sys, time
    from pathlib import Path
    target = Path(sys.argv[1])
    how = sys.argv[2]
    signum = getattr(signal, sys.argv[3])
    if how == "user-handler":
        signal.signal(signum, lambda s, f: (print("user handler", flush=True), os._exit(7)))
    if how == "vtu":
        import numpy as np
        from ddsolve.io import vtk
        real_inline = vtk._inline_base64
        def inline_then_terminate(data):      # VTKOutput has written the temporary file: terminate now
            os.kill(os.getpid(), signum)
            time.sleep(5)
            return real_inline(data)
        vtk._inline_base64 = inline_then_terminate
        from types import SimpleNamespace
        scene = SimpleNamespace(coords=np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), elements=np.array([[0, 1, 2]]))
        vtk.write_vtu(target, scene, {"u": np.zeros(3)}, {})
    else:
        from ddsolve.io.hdf5 import atomic_target
        with atomic_target(target) as tmp:
            tmp.write_bytes(b"x" * 1000)
            print(tmp.name, flush=True)
            os.kill(os.getpid(), signum)
            time.sleep(5)
    print("not terminated", flush=True)
""")


def _run(tmp_path, how: str, signame: str) -> subprocess.CompletedProcess:
    ext = ".vtu" if how == "vtu" else ".h5"
    return subprocess.run([sys.executable, "-c", CHILD, str(tmp_path / f"k{ext}"), how, signame],
                          capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
@pytest.mark.parametrize("how", ["hdf5", "vtu"])
def test_a_terminated_writer_leaves_no_file_and_dies_of_the_signal(tmp_path, how, signame):
    proc = _run(tmp_path, how, signame)
    assert proc.returncode == -getattr(signal, signame), proc.stderr
    assert "not terminated" not in proc.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_users_handler_is_left_alone(tmp_path):
    proc = _run(tmp_path, "user-handler", "SIGTERM")
    assert proc.returncode == 7 and "user handler" in proc.stdout
    # the user's handler ran instead of ours: the temporary file is the user's business
    assert [p.name.endswith(".tmp") for p in tmp_path.iterdir()] == [True]
