"""Structural check of a netgen ``.vol`` text before netgen reads it.

netgen's ``Mesh.Load`` trusts the file: a truncated file, a section with fewer
lines than its count, or an element that names a point beyond the point list
makes it (or NGSolve, later) crash with a segmentation fault, which no Python
``try`` catches. :func:`check_vol_text` reads the text once, in about the time
netgen's own load takes, and raises an :class:`~ddsolve.errors.InputError`
naming the first problem, so a bad file costs one line and exit status 2.

What is checked (the sections netgen writes for a 2-D mesh):

* the file starts with ``mesh3d`` and its mesh part ends with ``endmesh`` (not truncated;
  a mesh of an OCC geometry continues with the geometry, left to netgen);
* ``dimension`` is 2;
* every counted section (``points``, ``surfaceelements*``, ``volumeelements``,
  ``edgesegments*``, ``pointelements``, ``materials``, ``bcnames``,
  ``facedescriptors``, ``edgedescriptors``) has a non-negative integer count
  and exactly that many data lines;
* points have three finite coordinates; a surface element line has
  ``5 + np`` integers with np in {3, 4, 6, 8}; every point number in the
  surface elements, edge segments and point elements lies in 1..n_points.

Sections not listed are left to netgen.
"""
from __future__ import annotations

import re

import numpy as np

from ..errors import InputError

__all__ = ["check_vol_text"]

_HEADER = re.compile(r"^[ \t]*([A-Za-z][A-Za-z0-9_]*)[ \t]*\r?$", re.M)
_COUNTED = ("points", "surfaceelements", "volumeelements", "pointelements", "materials", "bcnames",
            "facedescriptors", "edgedescriptors")
_ELEMENT_SIZES = (3, 4, 6, 8)


def _data_lines(block: str) -> list[str]:
    return [ln for ln in (raw.strip() for raw in block.splitlines()) if ln and not ln.startswith("#")]


def _ints(lines: list[str], what: str, name: str) -> np.ndarray:
    try:
        return np.array(" ".join(lines).split(), dtype=np.int64)
    except ValueError:
        raise InputError("mesh", f"{name}: section {what!r} holds a value that is not an integer") from None


def check_vol_text(text: str, name: str = "mesh file") -> None:
    """Raise :class:`InputError` (field ``mesh``) if ``text`` is not a complete 2-D netgen mesh.

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
    for k, (_, end, word) in enumerate(heads[:last]):
        block = text[end:heads[k + 1][0]]
        key = next((p for p in ("edgesegments", "surfaceelements") if word.startswith(p)), word)
        if key in _COUNTED or key in ("edgesegments", "dimension"):
            sections[key] = _data_lines(block)
    dim = sections.get("dimension")
    if dim is not None and dim[:1] != ["2"]:
        raise InputError("mesh", f"{name}: only 2-D meshes are supported (dimension {' '.join(dim[:1]) or '?'})")
    for key, lines in sections.items():
        if key == "dimension":
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
        n_points = len(pts)
    if "surfaceelements" in sections:
        lines = sections["surfaceelements"][1:]          # (surfaceelementsuv: uv parameters follow)
        widths = np.fromiter((len(ln.split()) for ln in lines), dtype=np.int64, count=len(lines))
        try:
            vals = np.array(" ".join(lines).split(), dtype=float)
        except ValueError:
            raise InputError("mesh", f"{name}: section 'surfaceelements' holds a value that is not a number") from None
        starts = np.cumsum(widths) - widths                # first value of every line
        if lines and (widths < 5).any():
            raise InputError("mesh", f"{name}: a surface element line has fewer than 5 numbers")
        n_vertices = vals[starts + 4].astype(np.int64) if lines else np.zeros(0, dtype=np.int64)
        if not np.isin(n_vertices, _ELEMENT_SIZES).all() or (widths < 5 + n_vertices).any():
            raise InputError("mesh", f"{name}: a surface element has a bad number of points "
                                     f"(expected 3, 4, 6 or 8 after 5 header numbers)")
        take = np.repeat(starts + 5, n_vertices) + (np.arange(int(n_vertices.sum()))
                                                    - np.repeat(np.cumsum(n_vertices) - n_vertices, n_vertices))
        points = vals[take]
        if not np.array_equal(points, np.round(points)):
            raise InputError("mesh", f"{name}: section 'surfaceelements' names a point that is not an integer")
        _in_range(points.astype(np.int64), n_points, "surfaceelements", name)
    for key, n_cols in (("edgesegments", 2), ("pointelements", 1)):
        lines = sections.get(key, [None])[1:]
        if lines:
            firsts = [ln.split()[:n_cols] for ln in lines]
            if any(len(f) < n_cols for f in firsts):
                raise InputError("mesh", f"{name}: a line of section {key!r} is too short")
            _in_range(_ints([" ".join(f) for f in firsts], key, name), n_points, key, name)


def _in_range(points: np.ndarray, n_points: int, key: str, name: str) -> None:
    if points.size and (points.min() < 1 or points.max() > n_points):
        bad = int(points.min()) if points.min() < 1 else int(points.max())
        raise InputError("mesh", f"{name}: section {key!r} names point {bad}, but the mesh has "
                                 f"{n_points} points (numbered from 1)")
