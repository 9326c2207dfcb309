"""Unstructured meshes from the command line and YAML: bad input (one line, status 2, nothing written),
mesh files, and the ParaView output (``--output FILE.vtu``)."""
from __future__ import annotations

import base64
import json
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from ddsolve import solve
from ddsolve.cli import main
from ddsolve.spec import ProblemSpec

PREFIX = "ddsolve: error: "
U = ["--mesh", "unstructured"]


def refused(argv, field, capsys, tmp_path, monkeypatch):
    """``main(argv)`` in an empty cwd: status 2, one line naming ``field``, no file written."""
    cwd = tmp_path / "cwd"
    cwd.mkdir(parents=True)
    monkeypatch.chdir(cwd)
    t0 = time.perf_counter()
    code = main(["solve", *argv, "--output", "out.vtu"])
    seconds = time.perf_counter() - t0
    out, err = capsys.readouterr()
    assert code == 2 and out == "", err
    assert len(err.splitlines()) == 1 and err.startswith(f"{PREFIX}{field}:"), err
    assert "Traceback" not in err and seconds < 10.0
    assert list(cwd.iterdir()) == []
    return err.strip()


def _nonconforming_mesh(path: Path) -> Path:
    """Two bodies whose contact line x = 1 does not match: (1, 0.5) is a node of the right body only."""
    from netgen.csg import Pnt
    from netgen.meshing import Element1D, Element2D, FaceDescriptor, Mesh, MeshPoint

    m = Mesh(dim=2)
    a = [m.Add(MeshPoint(Pnt(x, y, 0))) for x, y in ((0, 0), (1, 0), (1, 1), (0, 1))]
    b = [m.Add(MeshPoint(Pnt(x, y, 0))) for x, y in ((1, 0), (2, 0), (2, 1), (1, 1), (1, 0.5))]
    m.Add(FaceDescriptor(surfnr=1, domin=1, bc=1))
    m.Add(FaceDescriptor(surfnr=2, domin=2, bc=1))
    m.SetMaterial(1, "left")
    m.SetMaterial(2, "right")
    for tri in ([a[0], a[1], a[2]], [a[0], a[2], a[3]]):
        m.Add(Element2D(1, tri))
    for tri in ([b[0], b[1], b[4]], [b[4], b[1], b[2]], [b[4], b[2], b[3]]):
        m.Add(Element2D(2, tri))
    m.Add(Element1D([a[1], a[2]], index=1))
    m.Add(Element1D([a[3], a[0]], index=2))
    m.SetBCName(0, "contact")
    m.SetBCName(1, "clamp")
    m.Save(str(path))
    return path


def _squares_mesh(path: Path) -> Path:
    """Two unit squares glued along x = 1 ("contact"), with outer sides "clampL" (x = 0) and "clampR" (x = 2)."""
    from netgen.occ import Glue, MoveTo, OCCGeometry

    left, right = MoveTo(0, 0).Rectangle(1, 1).Face(), MoveTo(1, 0).Rectangle(1, 1).Face()
    left.faces.name, right.faces.name = "left", "right"
    shape = Glue([left, right])
    for edge in shape.edges:
        edge.name = {0.0: "clampL", 1.0: "contact", 2.0: "clampR"}.get(round(edge.center.x, 9), "free")
    OCCGeometry(shape, dim=2).GenerateMesh(maxh=0.25).Save(str(path))
    return path


def _zero_area_mesh(path: Path) -> Path:
    """Three triangles of the unit square, one of them degenerate (its vertices on y = 0)."""
    from netgen.csg import Pnt
    from netgen.meshing import Element1D, Element2D, FaceDescriptor, Mesh, MeshPoint

    m = Mesh(dim=2)
    p = [m.Add(MeshPoint(Pnt(x, y, 0))) for x, y in ((0, 0), (1, 0), (1, 1), (0, 1), (0.5, 0))]
    m.Add(FaceDescriptor(surfnr=1, domin=1, bc=1))
    m.SetMaterial(1, "body")
    for tri in ([p[0], p[4], p[2]], [p[0], p[2], p[3]], [p[4], p[1], p[2]], [p[0], p[1], p[4]]):
        m.Add(Element2D(1, tri))
    m.Add(Element1D([p[3], p[0]], index=1))
    m.SetBCName(0, "clamp")
    m.Save(str(path))
    return path


@pytest.fixture(scope="module")
def mesh_files(tmp_path_factory):
    from ddsolve.scene.unstructured import mesh_geometry

    root = tmp_path_factory.mktemp("meshes")
    mesh_geometry("contact", maxh=0.2).Save(str(root / "membranes.vol"))
    (root / "text.vol").write_text("this is not a mesh\n")
    _nonconforming_mesh(root / "nonconforming.vol")
    _squares_mesh(root / "squares.vol")
    _zero_area_mesh(root / "zeroarea.vol")
    return root


BAD = [
    (U + ["--maxh", "0"], "maxh"),
    (U + ["--maxh", "-0.1"], "maxh"),
    (U + ["--maxh", "nan"], "maxh"),
    (U + ["--maxh", "1e-5"], "maxh"),                                   # too large: refused before meshing
    (U + ["--maxh", "0.01", "--refine", "9"], "refine"),
    (U + ["--refine", "-1"], "refine"),
    (U + ["--parts", "0"], "parts"),
    (U + ["--parts", "1000", "--maxh", "0.25"], "parts"),              # more parts than elements
    (U + ["--geometry", "disc"], "geometry"),
    (U + ["--problem", "multibody", "--geometry", "lshape"], "geometry"),
    (U + ["--subdomains", "4"], "subdomains"),
    (U + ["--elements", "8"], "elements"),
    (["--parts", "8"], "parts"),
    (["--maxh", "0.2"], "maxh"),
    (["--geometry", "hole"], "geometry"),
    (["--mesh", "triangles"], "mesh"),
    (["--method", "feti", "--primal", "vertices+edges"], "primal"),    # fetidp and bddc only
    (["--primal", "faces"], "primal"),
    (["--dirichlet", "left"], "dirichlet"),
    (U + ["--parts", "1"], "parts"),                                    # fetidp on one subdomain
    (U + ["--mesh-file", "/nonexistent/mesh.vol"], "mesh_file"),
    (["--mesh-file", "/nonexistent/mesh.vol"], "mesh_file"),            # needs --mesh unstructured
]


@pytest.mark.parametrize("argv,field", [pytest.param(a, f, id=" ".join(a)[:50]) for a, f in BAD])
def test_bad_input(argv, field, capsys, tmp_path, monkeypatch):
    refused(argv, field, capsys, tmp_path, monkeypatch)


def test_too_fine_is_refused_before_meshing(capsys, tmp_path, monkeypatch):
    import ddsolve.scene.unstructured as unstructured

    def never(*args, **kwargs):   # pragma: no cover - reaching it is the failure
        raise AssertionError("meshed before the size check")
    monkeypatch.setattr(unstructured, "mesh_geometry", never)
    line = refused(U + ["--maxh", "0.0005", "--refine", "2"], "refine", capsys, tmp_path, monkeypatch)
    assert "problem too large" in line


def test_output_must_be_vtu(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["solve", "--output", "solution.txt"]) == 2
    assert capsys.readouterr().err.startswith(f"{PREFIX}output:")
    assert main(["solve", "--output", "missing/dir/u.vtu"]) == 2
    assert capsys.readouterr().err.startswith(f"{PREFIX}output:")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("extra,field", [
    (["--mesh-file", "text.vol"], "mesh_file"),
    (["--mesh-file", "nonconforming.vol", "--problem", "contact", "--dirichlet", "clamp", "--parts", "1",
      "--method", "direct"], "contact_boundary"),
    (["--mesh-file", "membranes.vol", "--problem", "contact", "--dirichlet", "nope"], "dirichlet"),
    (["--mesh-file", "membranes.vol", "--problem", "contact", "--dirichlet", "clamp",
      "--contact-boundary", "nope"], "contact_boundary"),
    (["--mesh-file", "membranes.vol", "--problem", "contact", "--dirichlet", "clamp",
      "--bodies-materials", "body0,steel"], "bodies_materials"),
    (["--mesh-file", "membranes.vol", "--problem", "contact", "--dirichlet", "clamp",
      "--bodies-materials", "body0"], "bodies_materials"),                # body1 is in the mesh, not listed
    (["--mesh-file", "membranes.vol", "--maxh", "0.3"], "maxh"),
    (["--problem", "multibody", "--mesh-file", "membranes.vol", "--bodies", "3"], "bodies"),
    # review of 2026-11-25: scenes a method cannot solve, unbounded problems, broken meshes (they ran and
    # reported converged=false, or aborted under mpiexec)
    (["--mesh-file", "squares.vol", "--problem", "contact", "--method", "smalbe", "--dirichlet", "clampL,clampR"],
     "method"),
    (["--mesh-file", "squares.vol", "--problem", "contact", "--method", "smalbe", "--dirichlet", "clampR",
      "--f", "1"], "method"),                                              # body 1 floats, pressed onto body 2
    (["--mesh-file", "squares.vol", "--problem", "contact", "--dirichlet", "clampR"], "f"),   # pulled away
    (["--mesh-file", "squares.vol", "--problem", "contact", "--dirichlet", "clampL,contact"], "dirichlet"),
    (["--mesh-file", "zeroarea.vol", "--dirichlet", "clamp", "--parts", "2"], "mesh_file"),
    (["--mesh-file", "nonconforming.vol", "--problem", "multibody", "--method", "direct", "--dirichlet", "clamp",
      "--parts", "1"], "mesh_file"),                   # was tied at the coincident corners only, 'converged'
])
def test_bad_mesh_files(extra, field, mesh_files, capsys, tmp_path, monkeypatch):
    argv = [a if not a.endswith(".vol") else str(mesh_files / a) for a in extra]
    line = refused(U + argv, field, capsys, tmp_path, monkeypatch)
    if field == "contact_boundary" and "nonconforming" in " ".join(argv):
        assert "not a conforming interface" in line and "near (1, 0.5)" in line
    if "smalbe" in argv:
        assert "needs body 1 clamped and body 2 floating" in line
    if "multibody" in argv and "nonconforming" in " ".join(argv):
        # the corners (1, 0) and (1, 1) are two nodes each, and (1, 0.5) lies inside the left body's side
        assert "the mesh is not conforming near (1, 0): 5 boundary node(s) lie on another boundary edge" in line
    if "zeroarea.vol" in " ".join(argv):
        assert "1 degenerate triangle(s) of zero area, the first near (0.5, 0)" in line


def test_both_bodies_clamped_contact(mesh_files):
    """No floating body: the direct method (which kept one pair active) and the active set method agree, with
    contact (both pressed together) and without (pulled apart: no active pair, zero multipliers)."""
    for f, pressed in (("dostal:3,-1", True), ("dostal:-3,1", False)):       # patch loads on body 1, body 2
        runs = {m: solve(ProblemSpec(problem="contact", method=m, mesh="unstructured", parts=2, f=f,
                                     mesh_file=str(mesh_files / "squares.vol"), dirichlet="clampL,clampR",
                                     **({"rtol": 1e-10} if m != "direct" else {})))
                for m in ("direct", "active-set")}
        for run in runs.values():
            assert run.converged, run.reason
            assert run.extra["kkt_residual"] <= 1e-8
        assert runs["direct"].extra["n_active"] == runs["active-set"].extra["n_active"]
        e = runs["direct"].extra["energy"]
        assert abs(runs["active-set"].extra["energy"] - e) <= 1e-8 * abs(e)
        assert (runs["direct"].extra["n_active"] > 0) == pressed


def test_output_directory_must_take_a_file(capsys, tmp_path, monkeypatch):
    """A directory that exists but takes no file (/proc) is refused before the solve (was a traceback after it)."""
    monkeypatch.chdir(tmp_path)
    assert main(["solve", "--output", "/proc/u.vtu"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.splitlines()) == 1
    assert err.startswith(f"{PREFIX}output: cannot write in directory '/proc'")


def test_mesh_file_matches_builtin_contact(mesh_files):
    """The built-in membranes saved as .vol and read back as a mesh file give the same discrete problem."""
    common = dict(problem="contact", mesh="unstructured", parts=3, method="direct")
    builtin = solve(ProblemSpec(maxh=0.2, **common))
    from_file = solve(ProblemSpec(mesh_file=str(mesh_files / "membranes.vol"), dirichlet="clamp",
                                  bodies_materials="body0,body1", **common))
    assert from_file.ndof == builtin.ndof
    assert from_file.extra["n_active"] == builtin.extra["n_active"]
    assert abs(from_file.extra["energy"] - builtin.extra["energy"]) <= 1e-12 * abs(builtin.extra["energy"])


def test_yaml_scene(tmp_path, capsys, mesh_files):
    scene = tmp_path / "scene.yaml"
    scene.write_text(f"problem: contact\nmethod: smalbe\nmesh: unstructured\nmesh_file: {mesh_files / 'membranes.vol'}\n"
                     "dirichlet: clamp\ncontact_boundary: contact\nbodies_materials: body0,body1\nparts: 3\n")
    assert main(["solve", str(scene), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["converged"] and data["mesh"] == "unstructured" and data["parts"] == 3


@pytest.mark.parametrize("method", ["feti", "fetidp", "bddc"])
def test_cli_poisson_methods(method, capsys):
    assert main(["solve", *U, "--maxh", "0.2", "--parts", "4", "--method", method, "--rtol", "1e-10",
                 "--check", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["converged"] and data["error_vs_direct"] < 1e-8
    assert set(data["timings"]) == {"mesh", "partition", "assembly", "setup", "solve"}


# --------------------------------------------------------------------------- output
def _arrays(path: Path) -> tuple[dict[str, np.ndarray], int, int]:
    """The DataArrays of a .vtu (inline base64, UInt32 size header) and NumberOfPoints/Cells."""
    root = ET.parse(path).getroot()
    piece = root.find("UnstructuredGrid/Piece")
    arrays = {}
    for node in root.iter("DataArray"):
        assert node.attrib["format"] == "binary"
        raw = base64.b64decode(node.text.strip())
        nbytes = int(np.frombuffer(raw[:4], dtype="<u4")[0])
        dtype = {"Float64": "<f8", "Int32": "<i4", "UInt8": "u1"}[node.attrib["type"]]
        arrays[node.attrib["Name"]] = np.frombuffer(raw[4:4 + nbytes], dtype=dtype)
    return arrays, int(piece.attrib["NumberOfPoints"]), int(piece.attrib["NumberOfCells"])


@pytest.mark.parametrize("spec", [
    dict(problem="poisson", subdomains=2, elements=3),
    dict(problem="poisson", mesh="unstructured", maxh=0.2, parts=3, geometry="hole"),
    dict(problem="multibody", bodies=2, subdomains=2, elements=2),
    dict(problem="multibody", bodies=2, mesh="unstructured", maxh=0.25, parts=2),
    dict(problem="contact", subdomains=2, elements=3),
    dict(problem="contact", mesh="unstructured", maxh=0.25, parts=2),
], ids=lambda d: f"{d['problem']}-{d.get('mesh', 'structured')}")
def test_output_vtu(spec, tmp_path):
    from ddsolve.prepared import prepare

    target = tmp_path / "out" / "solution.vtu"
    target.parent.mkdir()
    result = solve(ProblemSpec(output=str(target), **spec))
    assert result.converged
    assert sorted(p.name for p in target.parent.iterdir()) == ["solution.vtu"]     # no temporary left
    arrays, n_points, n_cells = _arrays(target)
    scene = prepare(ProblemSpec(**spec)).scene
    width = scene.elements.shape[1]
    assert n_cells == scene.elements.shape[0] and n_points == width * n_cells   # vertices written per cell
    assert arrays["Points"].size == 3 * n_points
    names = {"u", "subdomain", "body", "rho"} | ({"multiplier", "gap", "contact_node"} if spec["problem"] == "contact"
                                                else set())
    assert names <= set(arrays)
    for name in names:
        assert arrays[name].size == n_points
    assert np.isclose(np.abs(arrays["u"]).max(), np.abs(result.u).max(), rtol=1e-12)
    assert set(np.unique(arrays["subdomain"]).astype(int)) == set(range(scene.n_subdomains))
    if spec["problem"] == "contact":
        assert arrays["multiplier"].min() >= 0 and arrays["multiplier"].max() > 0
        assert arrays["gap"].max() <= 1e-6
        on = arrays["contact_node"] == 1.0
        assert on.any() and not on.all() and np.all(arrays["multiplier"][~on] == 0)
