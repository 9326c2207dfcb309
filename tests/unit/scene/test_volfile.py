"""A netgen .vol file that would crash netgen (SIGSEGV) is refused with one InputError first."""
import gzip
import subprocess
import sys

import pytest

from ddsolve.errors import InputError
from ddsolve.scene.volfile import load_netgen_mesh
from ddsolve.scene.volfile import check_vol_text


@pytest.fixture(scope="module")
def vol_text(tmp_path_factory) -> str:
    from netgen.geom2d import unit_square

    path = tmp_path_factory.mktemp("vol") / "square.vol"
    unit_square.GenerateMesh(maxh=0.25).Save(str(path))
    return path.read_text()


def _replace_count(text: str, section: str, delta: int) -> str:
    lines = text.splitlines()
    i = lines.index(section)
    lines[i + 1] = str(int(lines[i + 1]) + delta)
    return "\n".join(lines) + "\n"


def _first_element_point(text: str, value: int) -> str:
    lines = text.splitlines()
    i = lines.index("surfaceelements") + 2
    fields = lines[i].split()
    fields[5] = str(value)
    lines[i] = " ".join(fields)
    return "\n".join(lines) + "\n"


def _field(text: str, section: str, column: int, value: str) -> str:
    """``text`` with one value of the first data line of ``section`` replaced."""
    lines = text.splitlines()
    i = lines.index(section) + 2
    fields = lines[i].split()
    fields[column] = value
    lines[i] = " ".join(fields)
    return "\n".join(lines) + "\n"


def test_a_complete_mesh_passes(vol_text):
    check_vol_text(vol_text)


@pytest.mark.parametrize("mutate, message", [
    (lambda t: t[: len(t) // 2], "incomplete"),
    (lambda t: t.replace("endmesh", ""), "incomplete"),
    (lambda t: _replace_count(t, "points", 1), "'points' announces"),
    (lambda t: _replace_count(t, "surfaceelements", -1), "'surfaceelements' announces"),
    (lambda t: _first_element_point(t, 10**6), "names point 1000000"),
    (lambda t: _first_element_point(t, 0), "names point 0"),
    (lambda t: t.replace("dimension\n2", "dimension\n3"), "only 2-D"),
    (lambda t: _field(t, "surfaceelements", 0, "nan"), "not finite"),             # each of these three
    (lambda t: _field(t, "edgesegmentsgi3", 5, "nan"), "not finite"),             # crashed netgen (SIGSEGV)
    (lambda t: t.replace("geomtype\n", "geomtype\ngeomtype\n", 1), "appears twice"),  # (a ValueError later)
    (lambda t: _field(t, "surfaceelements", 2, "1e308"), "whole number"),
    (lambda t: "hello\n" + t, "not a netgen mesh"),
])
def test_inconsistent_files_are_refused(vol_text, mutate, message):
    with pytest.raises(InputError, match=message) as info:
        check_vol_text(mutate(vol_text), "m.vol")
    assert info.value.field == "mesh"


def test_loader_refuses_before_netgen_reads(tmp_path, vol_text):
    """Each of these made netgen or NGSolve crash with a segmentation fault (measured: exit 139)."""
    for k, text in enumerate([vol_text[:300], _first_element_point(vol_text, 80),
                              _replace_count(vol_text, "edgesegmentsgi3", 1)]):
        path = tmp_path / f"bad{k}.vol"
        path.write_text(text)
        with pytest.raises(InputError):
            load_netgen_mesh(path)
    gz = tmp_path / "cut.vol.gz"
    gz.write_bytes(gzip.compress(vol_text.encode())[:200])
    with pytest.raises(InputError, match="cannot read"):
        load_netgen_mesh(gz)
    good = tmp_path / "good.vol"
    good.write_text(vol_text)
    assert len(load_netgen_mesh(good).Elements2D()) > 0


def test_cli_truncated_mesh_file_is_one_line_exit_2(tmp_path, vol_text):
    path = tmp_path / "cut.vol"
    path.write_text(vol_text[: len(vol_text) // 3])
    proc = subprocess.run([sys.executable, "-m", "ddsolve", "solve", "--mesh", "unstructured",
                           "--mesh-file", str(path), "--parts", "2"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "incomplete" in proc.stderr and proc.stdout == ""


def test_mesh_without_free_nodes_is_refused(tmp_path):
    """Every node on the Dirichlet boundary: no unknowns; an InputError naming dirichlet (was 'A: operator has size 0')."""
    from netgen.geom2d import unit_square

    from ddsolve.scene.unstructured import scene_from_mesh

    path = tmp_path / "coarse.vol"
    unit_square.GenerateMesh(maxh=0.5).Save(str(path))          # 8 nodes, all on the boundary
    with pytest.raises(InputError, match="no unknowns") as info:
        scene_from_mesh(path, parts=2)
    assert info.value.field == "dirichlet"


def test_empty_element_section_is_structurally_valid_and_refused_later(tmp_path, vol_text):
    """Zero surface elements: a consistent file (no crash in the check), refused as a mesh without elements."""
    from ddsolve.scene.unstructured import scene_from_mesh

    lines = vol_text.splitlines()
    i = lines.index("surfaceelements")
    n = int(lines[i + 1])
    text = "\n".join(lines[: i + 1] + ["0"] + lines[i + 2 + n:]) + "\n"
    check_vol_text(text)
    path = tmp_path / "empty.vol"
    path.write_text(text)
    with pytest.raises(InputError, match="no 2-D elements"):
        scene_from_mesh(path, parts=2)


@pytest.fixture(scope="module")
def occ_vol_text(tmp_path_factory) -> str:
    """A mesh of an OCC geometry: its .vol file continues with the serialised geometry after 'endmesh'."""
    from netgen.occ import Glue, MoveTo, OCCGeometry

    shape = Glue([MoveTo(0, 0).Rectangle(1, 1).Face(), MoveTo(1, 0).Rectangle(1, 1).Face()])
    path = tmp_path_factory.mktemp("occ") / "two.vol"
    OCCGeometry(shape, dim=2).GenerateMesh(maxh=0.25).Save(str(path))
    text = path.read_text()
    assert "TextOutArchive" in text[text.index("endmesh"):]
    return text


def test_damaged_geometry_part_is_not_read_without_refine(tmp_path, occ_vol_text):
    """One line dropped from the geometry part made netgen's reader loop for ever; without --refine only
    the (checked) mesh part is read, and the scene equals that of the intact file."""
    lines = occ_vol_text.splitlines()
    k = lines.index("endmesh")
    drop = next(i for i in range(k + 1, len(lines)) if lines[i].strip() == "1e-07")
    damaged = tmp_path / "damaged.vol"
    damaged.write_text("\n".join(lines[:drop] + lines[drop + 1:]) + "\n")
    intact = tmp_path / "intact.vol"
    intact.write_text(occ_vol_text)
    code = ("import numpy as np; from ddsolve.scene.unstructured import scene_from_mesh; "
            f"a = scene_from_mesh({str(intact)!r}, parts=2); b = scene_from_mesh({str(damaged)!r}, parts=2); "
            "assert np.array_equal(a.coords, b.coords) and np.array_equal(a.elements, b.elements); print('ok')")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


def test_mesh_part_alone_gives_the_same_arrays(tmp_path, occ_vol_text):
    import gc

    import numpy as np

    from ddsolve.scene.unstructured import netgen_arrays

    path = tmp_path / "two.vol"
    path.write_text(occ_vol_text)
    full = netgen_arrays(load_netgen_mesh(path, geometry=True))
    gc.collect()                                  # the meshes are gone: the arrays must not be views of them
    part = netgen_arrays(load_netgen_mesh(path, geometry=False))
    gc.collect()
    _ = [np.ones(10_000) for _ in range(50)]     # reuse freed memory
    for name in ("coords", "elements", "material", "segments", "segment_bc"):
        assert np.array_equal(getattr(full, name), getattr(part, name)), name
    assert full.material_names == part.material_names and full.bc_names == part.bc_names
    assert np.isfinite(full.coords).all() and full.coords.min() >= -1e-12 and full.coords.max() <= 2.0 + 1e-12


@pytest.mark.parametrize("first_two", [("2", "99"), ("2", "0"), ("1", "1"), ("2", "2"), ("5", "1")])
def test_a_triangle_of_an_undeclared_material_is_refused(tmp_path, first_two):
    """A triangle whose two leading numbers match no face descriptor: netgen made it a material 'default' that
    the file's 'materials' section does not declare, a one-triangle body, without a word (reviews of 2026-11-28:
    the second found that a check of the second number alone missed (1, 1), (2, 2) and (5, 1))."""
    from netgen.geom2d import SplineGeometry

    geo = SplineGeometry()
    p = [geo.AppendPoint(*q) for q in [(0, 0), (1, 0), (2, 0), (2, 1), (1, 1), (0, 1)]]
    for a, b, left, right in [(0, 1, 1, 0), (1, 2, 2, 0), (2, 3, 2, 0), (3, 4, 2, 0), (4, 5, 1, 0), (5, 0, 1, 0),
                              (1, 4, 1, 2)]:
        geo.Append(["line", p[a], p[b]], leftdomain=left, rightdomain=right, bc="side")
    geo.SetMaterial(1, "steel")
    geo.SetMaterial(2, "rubber")
    path = tmp_path / "two.vol"
    geo.GenerateMesh(maxh=0.5).Save(str(path))
    load_netgen_mesh(path)                                        # as netgen wrote it: accepted
    lines = path.read_text().splitlines()
    i = lines.index("surfaceelements") + 2
    fields = lines[i].split()
    fields[0], fields[1] = first_two
    lines[i] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"triangle 1 has a material that section 'materials' does not declare "
                                         r"\(it declares 1, 2; netgen read index 3\)"):
        load_netgen_mesh(path)
