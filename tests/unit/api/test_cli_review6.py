"""Regressions from the sixth black-box review (the CLI and the Python API on a user's own meshes).

Each case was a traceback, an unclear error naming no user field, or a result file lost: a failed
solve replaced a previous .vtu by one of NaN values.
"""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

pytest.importorskip("ngsolve")
from netgen.geom2d import SplineGeometry

from ddsolve import ProblemSpec, solve
from ddsolve.cli import main
from ddsolve.errors import InputError


def _rect(g, x0, y0, x1, y1, dom, bcs):
    p = [g.AppendPoint(*x) for x in [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]]
    for i in range(4):
        g.Append(["line", p[i], p[(i + 1) % 4]], bc=bcs[i], leftdomain=dom, rightdomain=0)


def _two_bodies(path: pathlib.Path, apart: bool) -> str:
    """Squares A (clamped on every side) and B (free); side by side with a shared side, or apart."""
    g = SplineGeometry()
    if apart:
        _rect(g, 0, 0, 1, 1, 1, ["clampA"] * 4)
        _rect(g, 2, 0, 3, 1, 2, ["free"] * 4)
    else:
        p = [g.AppendPoint(*x) for x in [(0, 0), (1, 0), (2, 0), (2, 1), (1, 1), (0, 1)]]
        for (i, j), bc, dom in zip([(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0), (1, 4)],
                                   ["free", "free", "free", "free", "free", "clampA", "contact"],
                                   [1, 2, 2, 2, 1, 1, 1]):
            g.Append(["line", p[i], p[j]], bc=bc, leftdomain=dom, rightdomain=2 if (i, j) == (1, 4) else 0)
    g.SetMaterial(1, "A")
    g.SetMaterial(2, "B")
    g.GenerateMesh(maxh=0.25).Save(str(path))
    return str(path)


def _square(path: pathlib.Path, maxh: float = 0.2) -> str:
    from netgen.geom2d import unit_square

    unit_square.GenerateMesh(maxh=maxh).Save(str(path))
    return str(path)


def test_one_part_of_a_mesh_file_is_refused_naming_parts(tmp_path, capsys):
    mesh = _square(tmp_path / "sq.vol")
    assert main(["solve", "--mesh", "unstructured", "--mesh-file", mesh, "--parts", "1", "--method", "fetidp"]) == 2
    assert capsys.readouterr().err == ("ddsolve: error: parts: method 'fetidp' needs at least 2 parts (one "
                                       "subdomain has no interface); use method 'direct'\n")      # was 'A: operator has size 0'


@pytest.mark.parametrize("method", ["feti-feti", "hybrid"])
def test_one_multibody_subdomain_is_refused_naming_subdomains(capsys, method):
    """One body of one subdomain: nothing to iterate on (a docs audit: 'A: operator has size 0')."""
    assert main(["solve", "--problem", "multibody", "--subdomains", "1", "--method", method]) == 2
    assert capsys.readouterr().err == (f"ddsolve: error: subdomains: method '{method}' needs at least 2 subdomains "
                                       "(one subdomain has no interface); use method 'direct'\n")


def test_fetidp_without_dual_interface_solves_directly(tmp_path):
    """Two triangles in two parts: every interface node is primal, no multiplier (was 'A: operator has size 0')."""
    g = SplineGeometry()
    _rect(g, 0, 0, 1, 1, 1, ["left", "b", "c", "d"])
    path = tmp_path / "two_triangles.vol"
    g.GenerateMesh(maxh=2.0).Save(str(path))
    res = solve(ProblemSpec(mesh="unstructured", mesh_file=str(path), parts=2, method="fetidp", dirichlet="left",
                            check=True))
    assert res.converged and res.nlambda == 0 and res.iterations == 0
    assert res.error_vs_direct < 1e-12


@pytest.mark.parametrize("method", ["feti-feti", "hybrid"])
def test_multibody_mesh_files_refuse_floating_bodies_of_one_part_and_untied_bodies(tmp_path, method):
    tied = _two_bodies(tmp_path / "tied.vol", apart=False)
    apart = _two_bodies(tmp_path / "apart.vol", apart=True)
    common = dict(mesh="unstructured", problem="multibody", dirichlet="clampA", method=method)
    with pytest.raises(InputError, match="parts: method .* needs 2 or more parts per floating body, body 2 has 1"):
        solve(ProblemSpec(mesh_file=tied, parts=1, **common))        # was a ValueError traceback
    with pytest.raises(InputError, match="dirichlet: body 2 is joined to no clamped body"):
        solve(ProblemSpec(mesh_file=apart, parts=2, **common))       # was 'Factor is exactly singular'
    res = solve(ProblemSpec(mesh_file=tied, parts=2, check=True, **common))
    assert res.converged and res.error_vs_direct < 1e-5


def test_a_broken_down_solve_keeps_the_previous_output(tmp_path, caplog):
    out = tmp_path / "keep.vtu"
    out.write_text("previous result")
    res = solve(ProblemSpec(rho=1e-300, f=1e300, output=str(out)))     # u = f / rho overflows: a NaN solution
    assert not res.converged and not np.all(np.isfinite(res.u))
    assert out.read_text() == "previous result"
    assert "not writing" in caplog.text


def test_paths_may_be_pathlib_and_names_long(tmp_path):
    mesh = pathlib.Path(_square(tmp_path / "sq.vol"))
    out = tmp_path / ("u" * 236 + ".vtu")                    # 240 characters: legal, the temporary name was not
    res = solve(ProblemSpec(mesh="unstructured", mesh_file=mesh, parts=4, method="bddc", output=out))
    assert res.converged and out.stat().st_size > 1000
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_hostile_sizes_are_one_line(tmp_path, capsys):
    """maxh = 1e-300 was a ZeroDivisionError, a coordinate of 1e308 a scipy ValueError, and a 2 MB .vol.gz
    that decompresses to gigabytes took 4.3 GB and 15 s before it was refused."""
    import gzip

    assert main(["solve", "--mesh", "unstructured", "--maxh", "1e-300"]) == 2
    assert "maxh: problem too large: an unbounded amount estimated" in capsys.readouterr().err
    path = pathlib.Path(_square(tmp_path / "sq.vol", maxh=0.5))
    text = path.read_text()
    first = text.index("points\n") + len("points\n")
    count_end = text.index("\n", first)
    line_end = text.index("\n", count_end + 1)
    coords = text[count_end + 1:line_end].split()
    big = tmp_path / "big.vol"
    big.write_text(text[:count_end + 1] + " ".join(["1e308", *coords[1:]]) + text[line_end:])
    assert main(["solve", "--mesh", "unstructured", "--mesh-file", str(big)]) == 2
    assert "a coordinate of magnitude 1e+308 exceeds 1e+150" in capsys.readouterr().err
    bomb = tmp_path / "bomb.vol.gz"
    with gzip.open(bomb, "wb", compresslevel=9) as fh:
        fh.write(b"mesh3d\n" + b" " * (200 * 2**20))
    assert main(["solve", "--mesh", "unstructured", "--mesh-file", str(bomb)]) == 2
    assert "decompresses to more than 64 MiB" in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [
    ("rho: 1:30\n", "rho: must be a positive finite number, got '1:30'"),           # YAML 1.1: 90
    ("subdomains: 1_0\n", "subdomains: must be an integer in [1, 2147483647], got '1_0'"),   # 10
    ("subdomains: 0x4\n", "subdomains: must be an integer in [1, 2147483647], got '0x4'"),
    ("subdomains: 4\nsubdomains: 8\n", "scene: key 'subdomains' is given twice (lines 1 and 2)"),   # last won
])
def test_scene_numbers_are_read_as_strictly_as_flags(tmp_path, capsys, text, message):
    scene = tmp_path / "s.yaml"
    scene.write_text(text)
    assert main(["solve", str(scene)]) == 2
    assert capsys.readouterr().err == f"ddsolve: error: {message}\n"


def test_scene_file_paths_are_relative_to_the_scene(tmp_path, monkeypatch):
    (tmp_path / "scenes").mkdir()
    _square(tmp_path / "scenes" / "sq.vol")
    (tmp_path / "scenes" / "s.yaml").write_text("mesh: unstructured\nmesh_file: sq.vol\nparts: 4\nmethod: bddc\n"
                                                "output: u.vtu\n")
    monkeypatch.chdir(tmp_path)
    assert main(["solve", "scenes/s.yaml"]) == 0            # was 'mesh_file: no such file: sq.vol'
    assert (tmp_path / "scenes" / "u.vtu").is_file() and not (tmp_path / "u.vtu").exists()


def test_poisson_on_a_mesh_of_several_materials_is_one_body(tmp_path):
    """Refused with advice ('list one material in bodies_materials') that the next check refused too."""
    mesh = _two_bodies(tmp_path / "two.vol", apart=False)
    res = solve(ProblemSpec(mesh="unstructured", mesh_file=mesh, parts=4, method="fetidp", dirichlet="clampA",
                            check=True))
    assert res.converged and res.bodies == 1 and res.error_vs_direct < 1e-6


@pytest.mark.parametrize("load", [-1e-300, -1e300])
def test_contact_check_is_scale_free(load):
    """error_vs_direct read 0.0 at f = -1e-300 (the norms underflowed) and null at -1e300."""
    ref = solve(ProblemSpec(problem="contact", subdomains=2, elements=4, f=-1.0, check=True))
    res = solve(ProblemSpec(problem="contact", subdomains=2, elements=4, f=load, check=True))
    assert res.error_vs_direct == pytest.approx(ref.error_vs_direct, rel=1e-6)
    assert res.extra["lambda_error_vs_direct"] == pytest.approx(ref.extra["lambda_error_vs_direct"], rel=1e-6)
