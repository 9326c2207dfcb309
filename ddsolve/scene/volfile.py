"""Structural check of a netgen ``.vol`` text before netgen reads it.

netgen's ``Mesh.Load`` trusts the file: a truncated file, a section with fewer
lines than its count, or an element that names a point beyond the point list
makes it (or NGSolve, later) crash with a segmentation fault, which no Python
``try`` catches. :func:`check_vol_text` reads the text once (0.29 s for 93k
triangles, three times netgen's own load; linear in the size) and raises an
:class:`~ddsolve.errors.InputError` naming the first problem, so a bad file
costs one line and exit status 2. The checks were completed by a fuzz of
mutated files (truncations, dropped and doubled lines, single values replaced
by 0, -1, 99999, 1e308, nan or a word): with the final rules, three runs (700,
700 and 500 mutations of a netgen and an OCC mesh file; the mutations that pass
the checks, up to 150 per run, loaded in a subprocess) had no crash and no hang.

What is checked (the sections netgen writes for a 2-D mesh):

* the file starts with ``mesh3d`` and its mesh part ends with ``endmesh`` (not truncated;
  a mesh of an OCC geometry continues with the geometry, left to netgen);
* ``dimension`` is 2;
* every counted section (``points``, ``surfaceelements*``, ``volumeelements``,
  ``edgesegments*``, ``pointelements``, ``materials``, ``bcnames``,
  ``facedescriptors``, ``edgedescriptors``) has a non-negative integer count
  and exactly that many data lines;
* a section header appears once, ``dimension`` and ``geomtype`` hold one integer;
* points have three finite coordinates, surface elements, edge segments and point
  elements hold finite numbers only; a surface element line has
  ``5 + np`` integers with np in {3, 4, 6, 8}; the integer columns of surface
  elements, edge segments and point elements are whole numbers in [-1, 2^31)
  (netgen reads them as C ints: NaN or 1e308 there crashed it); every point
  number in them lies in 1..n_points.

Sections not listed are left to netgen.
"""
from __future__ import annotations

import os
import re
from typing import Any

import numpy as np

from ..errors import InputError, brief

__all__ = ["check_vol_text", "declared_materials", "load_netgen_mesh"]

#: A .vol.gz may decompress to at most GZ_MAX_RATIO times its size, or GZ_MIN_LIMIT bytes if more.
GZ_MAX_RATIO = 50
GZ_MIN_LIMIT = 64 * 2**20

_HEADER = re.compile(r"^[ \t]*([A-Za-z][A-Za-z0-9_]*)[ \t]*\r?$", re.M)
_COUNTED = ("points", "surfaceelements", "volumeelements", "pointelements", "materials", "bcnames",
            "facedescriptors", "edgedescriptors")
_ELEMENT_SIZES = (3, 4, 6, 8)
_SINGLE = ("dimension", "geomtype")                 # sections of one integer value
#: str.translate table deleting the characters of an integer as netgen reads it (ASCII digits, signs)
_NOT_INTEGER = str.maketrans("", "", "0123456789+-")
_NOT_INTEGER_TEXT = str.maketrans("", "", "0123456789+- \t\r\n")      # the same, and the separators
_INT_MAX = 2**31 - 1                                # netgen reads these columns as C ints


#: Largest coordinate magnitude of a mesh file: squares and products of coordinates stay finite.
MAX_COORDINATE = 1e150

def _data_lines(block: str) -> list[str]:
    return [ln for ln in (raw.strip() for raw in block.splitlines()) if ln and not ln.startswith("#")]


def check_vol_text(text: str, name: str = "mesh file") -> int:
    """Raise :class:`InputError` (field ``mesh``) if ``text`` is not a complete 2-D netgen mesh.

    Returns the length of the mesh part of ``text`` (up to and including the ``endmesh`` line; a
    mesh of an OCC geometry continues with the serialised geometry, which is not checked).

    Parameters
    ----------
    text : str
        The whole ``.vol`` file (decompressed).
    name : str
        The file's name, for the message.
    """
    heads = [(m.start(), m.end(), m.group(1)) for m in _HEADER.finditer(text)]
    if not heads or heads[0][2] not in ("mesh3d", "mesh2d"):
        raise InputError("mesh", f"{name} is not a netgen mesh (a .vol file starts with 'mesh3d')")
    last = next((k for k, head in enumerate(heads) if head[2] == "endmesh"), None)
    if last is None:                 # (a mesh of an OCC geometry continues with the geometry after it)
        raise InputError("mesh", f"{name} is incomplete: the mesh part of a .vol file ends with 'endmesh' "
                                 f"(truncated file?)")
    sections: dict[str, list[str]] = {}
    seen: set[str] = set()
    for k, (_, end, word) in enumerate(heads[:last]):
        if word in seen:             # netgen reads the second one as data of the first: garbage after it
            raise InputError("mesh", f"{name}: section {word!r} appears twice")
        seen.add(word)
        block = text[end:heads[k + 1][0]]
        key = next((p for p in ("edgesegments", "surfaceelements") if word.startswith(p)), word)
        if key in _COUNTED or key in ("edgesegments",) + _SINGLE:
            sections[key] = _data_lines(block)
    for key in _SINGLE:
        value = sections.get(key)
        if value is not None and (len(value) != 1 or not re.fullmatch(r"\d+", value[0])):
            raise InputError("mesh", f"{name}: section {key!r} must hold one integer")
    dim = sections.get("dimension")
    if dim is not None and dim != ["2"]:
        raise InputError("mesh", f"{name}: only 2-D meshes are supported (dimension {dim[0]})")
    for key, lines in sections.items():
        if key in _SINGLE:
            continue
        if not lines or not re.fullmatch(r"\d+", lines[0]):
            raise InputError("mesh", f"{name}: section {key!r} has no count")
        count = int(lines[0])
        if len(lines) - 1 != count:
            raise InputError("mesh", f"{name}: section {key!r} announces {count} lines but has {len(lines) - 1}")
    n_points = 0
    if "points" in sections:
        pts = sections["points"][1:]
        try:
            xyz = np.array(" ".join(pts).split(), dtype=float)
        except ValueError:
            raise InputError("mesh", f"{name}: section 'points' holds a value that is not a number") from None
        if xyz.size != 3 * len(pts) or not np.isfinite(xyz).all():
            raise InputError("mesh", f"{name}: every point needs three finite coordinates")
        if xyz.size and np.abs(xyz).max() > MAX_COORDINATE:     # squared distances and areas would overflow
            raise InputError("mesh", f"{name}: a coordinate of magnitude {np.abs(xyz).max():.3g} exceeds "
                                     f"{MAX_COORDINATE:g} (rescale the mesh)")
        n_points = len(pts)
    if "surfaceelements" in sections:
        lines = sections["surfaceelements"][1:]          # (surfaceelementsuv: uv parameters follow)
        widths = np.fromiter((len(ln.split()) for ln in lines), dtype=np.int64, count=len(lines))
        joined = " ".join(lines)
        # every column an integer as netgen reads it (digits and signs only): the usual file, checked on the
        # text without keeping its tokens (168 MB more at 580k triangles, a review); else token by token
        plain = not joined.translate(_NOT_INTEGER_TEXT)
        try:
            vals = np.array(joined.split(), dtype=float)
        except ValueError:
            raise InputError("mesh", f"{name}: section 'surfaceelements' holds a value that is not a number") from None
        if not np.isfinite(vals).all():
            raise InputError("mesh", f"{name}: section 'surfaceelements' holds a value that is not finite")
        starts = np.cumsum(widths) - widths                # first value of every line
        if lines and (widths < 5).any():
            raise InputError("mesh", f"{name}: a surface element line has fewer than 5 numbers")
        head_at = (starts[:, None] + np.arange(5)).ravel() if lines else np.zeros(0, dtype=np.int64)
        header = vals[head_at]
        _integers(header, "surfaceelements", name)
        tokens = None if plain else joined.split()
        if tokens is not None:
            _integer_tokens(tokens, head_at, "surfaceelements", name)
        n_vertices = header[4::5].astype(np.int64)
        if not np.isin(n_vertices, _ELEMENT_SIZES).all() or (widths < 5 + n_vertices).any():
            raise InputError("mesh", f"{name}: a surface element has a bad number of points "
                                     f"(expected 3, 4, 6 or 8 after 5 header numbers)")
        take = np.repeat(starts + 5, n_vertices) + (np.arange(int(n_vertices.sum()))
                                                    - np.repeat(np.cumsum(n_vertices) - n_vertices, n_vertices))
        points = vals[take]
        _integers(points, "surfaceelements", name)
        if tokens is not None:
            _integer_tokens(tokens, take, "surfaceelements", name)
        del joined, tokens
        _in_range(points.astype(np.int64), n_points, "surfaceelements", name)
        _no_repeated_triangles(points.astype(np.int64), n_vertices, name)
    # integer columns: edge segments p1 p2 trignum1 trignum2 (and the descriptor number, column 7, of
    # the gi3 form), point elements pnum index; the first n_points of them name points
    for key, int_cols, n_point_cols in (("edgesegments", (0, 1, 2, 3), 2), ("pointelements", (0, 1), 1)):
        lines = sections.get(key, [None])[1:]
        if lines:
            fields = [ln.split() for ln in lines]
            cols = int_cols + ((6,) if key == "edgesegments" and all(len(f) >= 7 for f in fields) else ())
            if any(len(f) < len(int_cols) for f in fields):
                raise InputError("mesh", f"{name}: a line of section {key!r} is too short")
            _integer_tokens([f[c] for f in fields for c in cols], None, key, name)
            try:
                table = np.array([[float(f[c]) for c in cols] for f in fields])
                every = np.array(" ".join(lines).split(), dtype=float)       # the float columns too
            except ValueError:
                raise InputError("mesh", f"{name}: section {key!r} holds a value that is not a number") from None
            if not np.isfinite(every).all():
                raise InputError("mesh", f"{name}: section {key!r} holds a value that is not finite")
            _integers(table, key, name)
            _in_range(table[:, :n_point_cols].astype(np.int64), n_points, key, name)
    end = text.find("\n", heads[last][1])
    return len(text) if end < 0 else end + 1


def declared_materials(text: str) -> np.ndarray | None:
    """The material indices a ``materials`` section of a checked ``.vol`` text declares (None without one)."""
    heads = [(m.start(), m.end(), m.group(1)) for m in _HEADER.finditer(text)]   # as check_vol_text reads it
    for k, (_, end, word) in enumerate(heads):
        if word != "materials":
            continue
        lines = _data_lines(text[end:heads[k + 1][0] if k + 1 < len(heads) else len(text)])
        try:
            return np.array([int(ln.split()[0]) for ln in lines[1:1 + int(lines[0])]], dtype=np.int64)
        except (ValueError, IndexError):
            return None
    return None


def _integers(values: np.ndarray, key: str, name: str) -> None:
    """Integer columns: whole numbers in [-1, 2^31) (NaN, 1e308 or 2.5 made netgen crash)."""
    ok = np.isfinite(values) & (values == np.round(values)) & (values >= -1) & (values <= _INT_MAX)
    if not ok.all():
        bad = float(values[~ok].ravel()[0])
        raise InputError("mesh", f"{name}: section {key!r} holds {bad:g} where a whole number (at least -1) "
                                 f"belongs")


def _integer_tokens(tokens: list[str], at: np.ndarray | None, key: str, name: str) -> None:
    """The integer columns written as integers: netgen reads them with C++ ``>> int``, which stops at the
    '.' of ``20.0`` (or the 'e' of ``2e1``) and reads the rest as the next number; that misaligned the
    element table and crashed netgen (SIGSEGV, a review of 2026-11-27)."""
    picked = tokens if at is None else [tokens[i] for i in at.tolist()]
    if "".join(picked).translate(_NOT_INTEGER):     # a character other than an ASCII digit or a sign
        bad = next(t for t in picked if t.translate(_NOT_INTEGER))
        raise InputError("mesh", f"{name}: section {key!r} holds {brief(bad)} where an integer (written "
                                 f"without a decimal point or exponent) belongs")


def _no_repeated_triangles(points: np.ndarray, n_vertices: np.ndarray, name: str) -> None:
    """Refuse a triangle listed twice (the same three points): the two overlap, and the assembly would
    count the element twice without a word (a review)."""
    if n_vertices.size == 0 or not np.all(n_vertices == 3):
        return
    tri = np.sort(points.reshape(-1, 3), axis=1)
    order = np.lexsort(tri.T[::-1])
    same = np.all(tri[order[1:]] == tri[order[:-1]], axis=1)
    if same.any():
        first, second = sorted((int(order[np.argmax(same)]), int(order[np.argmax(same) + 1])))
        raise InputError("mesh", f"{name}: surface elements {first + 1} and {second + 1} are the same triangle "
                                 f"(points {', '.join(str(int(p)) for p in tri[order[np.argmax(same)]])}): "
                                 f"overlapping elements")


def _in_range(points: np.ndarray, n_points: int, key: str, name: str) -> None:
    if points.size and (points.min() < 1 or points.max() > n_points):
        bad = int(points.min()) if points.min() < 1 else int(points.max())
        raise InputError("mesh", f"{name}: section {key!r} names point {bad}, but the mesh has "
                                 f"{n_points} points (numbered from 1)")


def load_netgen_mesh(path: str | os.PathLike, geometry: bool = True) -> Any:
    """Load a netgen ``.vol`` (or ``.vol.gz``) file, checking that it is one.

    Parameters
    ----------
    path : path
    geometry : bool
        Also read the geometry that a mesh of an OCC geometry carries after its mesh part
        (needed by ``Refine()`` to put new boundary points on curved boundaries). Without it,
        only the checked mesh part reaches netgen: a damaged geometry part made netgen's
        reader loop for ever (measured: one line dropped from it), and it is not checked.

    Raises
    ------
    InputError
        ``mesh``: missing file, a file that is not a netgen mesh, or one that netgen would
        crash on (:func:`~ddsolve.scene.volfile.check_vol_text`).
    """
    import gzip
    import tempfile

    from netgen.meshing import Mesh as NGMesh

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("mesh", f"no such file: {path}")
    opener = gzip.open if path.endswith(".gz") else open
    # a .gz is read in blocks up to GZ_MAX_RATIO times its size (at least GZ_MIN_LIMIT): a mesh's text
    # compresses about 5:1, and a 2 MB compression bomb reached 4.3 GB before it was refused
    limit = max(GZ_MAX_RATIO * os.path.getsize(path), GZ_MIN_LIMIT) if path.endswith(".gz") else None
    try:
        with opener(path, "rb") as fh:
            if limit is None:
                data = fh.read()
            else:
                data = fh.read(limit + 1)
                if len(data) > limit:
                    raise InputError("mesh", f"{path} decompresses to more than {limit / 2**20:.0f} MiB "
                                             f"({GZ_MAX_RATIO}x its size): not a gzipped netgen mesh")
            text = data.decode("latin-1")
    except (OSError, EOFError) as exc:           # EOFError: a truncated .gz
        raise InputError("mesh", f"cannot read {path}: {exc}") from None
    mesh_end = check_vol_text(text, path)        # netgen crashes (SIGSEGV) on a truncated or inconsistent file
    try:                                         # netgen's names reach Python as UTF-8 (a bcname byte 0xff:
        data[:mesh_end].decode("utf-8")          # a UnicodeDecodeError traceback, a review); latin-1 keeps
    except UnicodeDecodeError as exc:            # byte and character offsets equal
        raise InputError("mesh", f"{path} holds bytes that are not UTF-8 text (byte {exc.start}): "
                                 f"not a netgen mesh, or a name in another encoding") from None
    ngmesh = NGMesh(dim=2)
    try:
        if geometry or not text[mesh_end:].strip():
            ngmesh.Load(path)
        else:                                    # the mesh part alone
            with tempfile.TemporaryDirectory() as tmp:
                part = os.path.join(tmp, "mesh.vol")
                with open(part, "w", encoding="latin-1") as fh:
                    fh.write(text[:mesh_end])
                ngmesh.Load(part)
    except Exception as exc:  # netgen raises its own NgException
        raise InputError("mesh", f"netgen cannot read {path}: {exc}") from None
    _check_declared_materials(ngmesh, declared_materials(text[:mesh_end]), path)
    return ngmesh


def _check_declared_materials(ngmesh: Any, declared: np.ndarray | None, path: str) -> None:
    """Refuse a file whose triangle netgen read into a material the ``materials`` section does not declare.

    netgen matches a triangle's two leading numbers against its face descriptors and makes an unmatched one
    a new material named "default": a one-triangle body of a multibody scene, or a silent part of a poisson
    one (a review). Read from netgen's own elements, so every such line is found. Files without a
    ``materials`` section are not checked.
    """
    if declared is None or declared.size == 0:
        return
    index = np.asarray(ngmesh.Elements2D().NumPy()["index"], dtype=np.int64)
    bad = np.flatnonzero(~np.isin(index, declared))
    if bad.size:
        raise InputError("mesh", f"{path}: triangle {int(bad[0]) + 1} has a material that section 'materials' "
                                 f"does not declare (it declares {', '.join(map(str, declared))}; netgen read "
                                 f"index {int(index[bad[0]])}): check the triangle's first two numbers")
