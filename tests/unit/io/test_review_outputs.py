"""Outputs and mesh files: defects found by a black-box review of the CLI's files (2026-11-27)."""
import json
import os
import resource
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from ddsolve import ProblemSpec, solve
from ddsolve.errors import InputError, OutputError

CLI = [sys.executable, "-m", "ddsolve", "solve"]


def run(args, cwd, **kwargs):
    return subprocess.run(CLI + args, cwd=cwd, capture_output=True, text=True, timeout=120, **kwargs)


@pytest.fixture(scope="module")
def vol_text(tmp_path_factory):
    from netgen.geom2d import unit_square
    path = tmp_path_factory.mktemp("mesh") / "square.vol"
    unit_square.GenerateMesh(maxh=0.5).Save(str(path))
    return path.read_text()


def _with_surface_point(text: str, replace) -> str:
    """``text`` with the last point number of the first surface element rewritten by ``replace``."""
    lines = text.split("\n")
    at = lines.index("surfaceelements") + 2
    fields = lines[at].split()
    fields[-1] = replace(fields[-1])
    lines[at] = " " + " ".join(fields)
    return "\n".join(lines)


@pytest.mark.parametrize("spelling", ["{}.0", "{}e0", "{}."])
def test_integer_columns_written_as_floats_are_refused(tmp_path, vol_text, spelling):
    """'20.0' passed the whole-number check and netgen's >> int misread it: SIGSEGV (exit 139)."""
    path = tmp_path / "float.vol"
    path.write_text(_with_surface_point(vol_text, spelling.format))
    proc = run(["--mesh", "unstructured", "--mesh-file", str(path)], tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "where an integer (written without a decimal point or exponent) belongs" in proc.stderr
    assert proc.stderr.count("\n") == 1


def test_mesh_names_that_are_not_utf8_are_refused(tmp_path, vol_text):
    path = tmp_path / "names.vol"
    data = vol_text.encode()
    path.write_bytes(data.replace(b"\tbottom\n", b"\tbott\xffm\n", 1))
    assert b"bott\xffm" in path.read_bytes()
    with pytest.raises(InputError, match="not UTF-8 text"):
        solve(ProblemSpec(mesh="unstructured", mesh_file=str(path), method="bddc"))


def test_a_failed_write_keeps_the_result_and_the_old_file(tmp_path):
    """A file size limit: NGSolve wrote a truncated file (struct.error) or the rewrite failed (EFBIG), both
    tracebacks with the result lost. Now one line, exit 2, the result printed, the old file kept."""
    old = tmp_path / "u.vtu"
    old.write_text("previous result")

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))

    proc = run(["--subdomains", "4", "--elements", "16", "--output", "u.vtu", "--json"], tmp_path, preexec_fn=limit)
    assert proc.returncode == 2
    assert proc.stderr.startswith("ddsolve: error: output: could not write 'u.vtu'") and proc.stderr.count("\n") == 1
    assert json.loads(proc.stdout)["converged"] is True
    assert old.read_text() == "previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["u.vtu"]


def test_output_error_carries_the_result(tmp_path, monkeypatch):
    import ddsolve.io.vtk as vtk

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(vtk, "write_vtu", full)
    with pytest.raises(OutputError, match="^output: could not write .*No space left on device") as info:
        solve(ProblemSpec(subdomains=2, elements=4, output=str(tmp_path / "u.vtu")))
    assert info.value.result.converged and info.value.result.u.size == 49


def test_truncated_vtk_data_is_an_os_error():
    from ddsolve.io.vtk import _inline_base64
    head = (b'<VTKFile header_type="UInt32"><DataArray type="Float64" format="appended" offset="0">'
            b'</DataArray><AppendedData encoding="raw">_')
    with pytest.raises(OSError, match="incomplete"):
        _inline_base64(head + (64).to_bytes(4, "little") + b"\0" * 10)


def test_replacing_keeps_permissions_and_follows_links(tmp_path):
    private = tmp_path / "private.vtu"
    private.write_text("old")
    private.chmod(0o600)
    real = tmp_path / "real.vtu"
    real.write_text("old")
    (tmp_path / "link.vtu").symlink_to(real.name)
    for target in ("private.vtu", "link.vtu"):
        solve(ProblemSpec(subdomains=2, elements=4, output=str(tmp_path / target)))
    assert stat.S_IMODE(private.stat().st_mode) == 0o600 and private.read_text().startswith("<?xml")
    assert (tmp_path / "link.vtu").is_symlink() and real.read_text().startswith("<?xml")


@pytest.mark.parametrize("args, message", [
    (["--output", ".vtu"], "output: needs a file name before '.vtu'"),
    (["--output", "a" * 252 + ".vtu"], "output: file name of 256 bytes, longer than the 255"),
    (["--output", ""], "output: is empty"),
    (["--mesh", "unstructured", "--mesh-file", " "], "mesh_file: is empty"),
])
def test_output_names_refused_before_the_solve(tmp_path, args, message):
    proc = run(args, tmp_path)
    assert proc.returncode == 2 and proc.stderr.startswith(f"ddsolve: error: {message}"), proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_output_that_is_the_scene_file_is_refused(tmp_path):
    scene = tmp_path / "s.vtu"
    scene.write_text("subdomains: 2\noutput: s.vtu\n")
    proc = run([str(scene)], tmp_path)
    assert proc.returncode == 2 and "s.vtu' is the scene file itself" in proc.stderr
    assert scene.read_text() == "subdomains: 2\noutput: s.vtu\n"


def test_a_closed_pipe_is_quiet(tmp_path):
    proc = subprocess.run(" ".join(CLI + ["--json"]) + " | head -c 10", shell=True, cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.stdout == '{"problem"' and proc.stderr == ""


def _written_cells(path):
    """Points (n, 3) and the cells (lists of point numbers) of a .vtu this package wrote (inline base64)."""
    import base64
    import re

    import numpy as np

    text = Path(path).read_text()

    def array(name, dtype):
        blob = re.search(rf'Name="{name}"[^>]*>\s*(\S+)\s*<', text).group(1)
        return np.frombuffer(base64.b64decode(blob)[4:], dtype=dtype)

    points = array("Points", np.float64).reshape(-1, 3)
    conn, offsets = array("connectivity", np.int32), array("offsets", np.int32)
    return points, np.split(conn, offsets[:-1])


@pytest.mark.parametrize("scene", [{"subdomains": 2, "elements": 2},                        # quadrilaterals
                                   {"mesh": "unstructured", "maxh": 0.3, "parts": 2, "method": "bddc"},
                                   {"mesh": "unstructured", "geometry": "hole", "maxh": 0.2, "parts": 4,
                                    "method": "bddc"}])
def test_cells_are_written_counterclockwise(tmp_path, scene):
    """Read back from the written file (a review: the helper was tested, NGSolve's output reversed the
    triangles, and every written triangle was clockwise)."""
    import numpy as np

    target = tmp_path / "u.vtu"
    solve(ProblemSpec.from_mapping({**scene, "output": str(target)}))
    points, cells = _written_cells(target)
    areas = [np.sum(points[c, 0] * np.roll(points[c, 1], -1) - np.roll(points[c, 0], -1) * points[c, 1])
             for c in cells]
    assert len(cells) > 0 and min(areas) > 0


def test_rho_is_written_per_cell(tmp_path):
    import re
    import base64
    import numpy as np
    target = tmp_path / "u.vtu"
    solve(ProblemSpec(subdomains=2, elements=2, rho="checkerboard:100", output=str(target)))
    text = target.read_text()
    blob = re.search(r'Name="rho"[^>]*>\s*(\S+)\s*<', text).group(1)
    values = np.frombuffer(base64.b64decode(blob)[4:], dtype=np.float64)
    assert sorted(set(values.tolist())) == [1.0, 100.0] and values.size == 16 * 4


def test_a_repeated_triangle_is_refused(tmp_path, vol_text):
    lines = vol_text.split("\n")
    at = lines.index("surfaceelements")
    count = int(lines[at + 1])
    lines[at + 1] = str(count + 1)
    lines.insert(at + 2, lines[at + 2])                  # the first element twice
    path = tmp_path / "twice.vol"
    path.write_text("\n".join(lines))
    with pytest.raises(InputError, match="surface elements 1 and 2 are the same triangle"):
        solve(ProblemSpec(mesh="unstructured", mesh_file=str(path), method="bddc"))


def test_a_dangling_link_does_not_create_its_directory(tmp_path):
    """--output through a symbolic link to nowhere/x.vtu: refused like nowhere/x.vtu itself (a review: the
    directory nowhere/ was created)."""
    link = tmp_path / "dangling.vtu"
    link.symlink_to("nowhere/x.vtu")
    with pytest.raises(InputError, match=r"^output: directory .*nowhere' does not exist"):
        solve(ProblemSpec(subdomains=2, elements=2, output=str(link)))
    assert not (tmp_path / "nowhere").exists()


@pytest.mark.parametrize("maxiter, converged", [(1, 0.0), (1000, 1.0)])
def test_the_file_says_whether_the_solve_converged(tmp_path, caplog, maxiter, converged):
    """A solve that did not converge replaced an existing file with its last iterate and nothing in the file
    said so (a review): the field 'converged' is 0 then on every cell, and a warning names the file. It is a point
    field, as every field of the file (the warning called it a cell field; a review)."""
    import base64
    import re

    import numpy as np

    target = tmp_path / "u.vtu"
    with caplog.at_level("WARNING"):
        res = solve(ProblemSpec(subdomains=4, elements=8, maxiter=maxiter, output=str(target)))
    assert res.converged is bool(converged)
    blob = re.search(r'Name="converged"[^>]*>\s*(\S+)\s*<', target.read_text()).group(1)
    values = np.frombuffer(base64.b64decode(blob)[4:], dtype=np.float64)
    assert values.size == 1024 * 4 and set(values.tolist()) == {converged}      # 4 x 4 x 8 x 8 cells
    warned = [r for r in caplog.records if "did not converge" in r.getMessage() and "u.vtu" in r.getMessage()]
    assert len(warned) == int(not converged)
    assert all("point field 'converged' is 0" in r.getMessage() for r in warned)
    assert re.search(r'<PointData[^>]*>(?:(?!</PointData>).)*Name="converged"', target.read_text(), re.S)


@pytest.mark.parametrize("below", ["u.vtu", "sub/u.vtu"])
def test_an_output_path_through_a_file_names_the_file(tmp_path, below):
    """--output ex1.py/u.vtu, ex1.py a regular file, said "directory '.../ex1.py' does not exist" (a review)."""
    (tmp_path / "ex1.py").write_text("x = 1\n")
    with pytest.raises(InputError, match=r"^output: '.*ex1\.py' is a file, not a directory$"):
        solve(ProblemSpec(subdomains=2, elements=2, output=str(tmp_path / "ex1.py" / below)))
    assert (tmp_path / "ex1.py").read_text() == "x = 1\n"
