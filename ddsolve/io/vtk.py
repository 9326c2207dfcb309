"""Solution output for ParaView: one ``.vtu`` file written through NGSolve's ``VTKOutput``.

The scene's mesh (Q1 quadrilaterals or P1 triangles, every body with its own
copy of its interface nodes) is handed to NGSolve as one mesh; nodal fields are
first-order H1 grid functions on it (dof k = node k), element fields
lowest-order L2 grid functions (dof e = element e). ``VTKOutput`` writes every
field at the vertices of every cell (NumberOfPoints = sum over the cells of
their vertices, 4 per Q1 cell, 3 per P1 cell), so a per-element field is
piecewise constant in ParaView and a field discontinuous across bodies shows
its jump.

``VTKOutput`` writes its data as a raw ``AppendedData`` block, which is not
well-formed XML; :func:`_inline_base64` rewrites every ``DataArray`` inline as
VTK's base64 ``binary`` format (same bytes, UInt32 size header), so the file is
plain XML (``xml.etree`` parses it) and ParaView reads it unchanged.

Written atomically: VTKOutput writes ``<tmp>.vtu`` (it appends ``.vtu`` to
its filename argument) beside the target, the file is rewritten in memory and
renamed onto the target with :func:`os.replace`.
"""
from __future__ import annotations

import base64
import errno
import os
import re
import struct
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

import numpy as np

from .cleanup import removed_on_termination, replace_onto, resolved_target

if TYPE_CHECKING:  # pragma: no cover
    from ..scene import Scene

__all__ = ["write_vtu", "solution_fields"]

_ARRAY = re.compile(rb'(<DataArray\b[^>]*?)format="appended" offset="(\d+)"([^>]*>)\s*(</DataArray>)')


def _inline_base64(data: bytes) -> bytes:
    """A VTK XML file with raw appended data as the same file with inline base64 ``binary`` arrays."""
    marker = data.find(b"<AppendedData")
    if marker < 0:
        return data
    start = data.index(b"_", data.index(b">", marker)) + 1
    blob = data[start:]
    header = data[:marker]
    if b'header_type="UInt64"' in header:
        size_fmt, size_len = "<Q", 8
    else:
        size_fmt, size_len = "<I", 4

    def inline(match: re.Match[bytes]) -> bytes:
        offset = int(match.group(2))
        nbytes = struct.unpack_from(size_fmt, blob, offset)[0] if offset + size_len <= len(blob) else None
        if nbytes is None or offset + size_len + nbytes > len(blob):
            # NGSolve does not report a failed write (a file size limit, a full disk): its file is short
            raise OSError(errno.EIO, "the VTK data NGSolve wrote is incomplete (a file size limit or a full disk?)")
        chunk = blob[offset:offset + size_len + nbytes]
        return (match.group(1) + b'format="binary"' + match.group(3) + b"\n" + base64.b64encode(chunk)
                + b"\n" + match.group(4))

    body = _ARRAY.sub(inline, header)
    return body.rstrip() + b"\n</VTKFile>\n"


def _counterclockwise(coords: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """``elements`` (n, 3 or 4) ordered so that the written cells are counter-clockwise (positive signed
    area, VTK's convention).

    Quadrilaterals are given counter-clockwise. NGSolve's VTK output writes a triangle's vertices in the
    reverse of the order netgen was given them, so triangles are given clockwise (a review found every
    written triangle clockwise while this function made them counter-clockwise;
    ``tests/unit/io/test_review_outputs.py`` reads the written file back).
    """
    x, y = coords[elements, 0], coords[elements, 1]
    area = np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    flip = area > 0 if elements.shape[1] == 3 else area < 0
    if not flip.any():
        return elements
    out = elements.copy()
    out[flip] = out[flip][:, ::-1]
    return out


def write_vtu(path: str | os.PathLike, scene: "Scene", nodal: Mapping[str, np.ndarray],
              cellwise: Mapping[str, np.ndarray]) -> Path:
    """Write nodal and per-element fields of a scene to a ``.vtu`` file, atomically.

    Parameters
    ----------
    path : path-like
        Target file; must end in ``.vtu``.
    scene : Scene
        Coordinates (n_nodes, 2) and elements (n_elements, 3 or 4).
    nodal : mapping of str to ndarray, shape (n_nodes,)
        Fields with one value per scene node (body copies separate).
    cellwise : mapping of str to ndarray, shape (n_elements,)
        Fields with one value per element.

    Returns
    -------
    Path
        The written file.
    """
    import ngsolve as ngs
    from netgen.meshing import Mesh as NGMesh

    path = resolved_target(path)
    if path.suffix.lower() != ".vtu":
        raise ValueError(f"output must be a .vtu file, got {path}")
    from ..scene.scene import check_mesh_arrays

    # netgen's AddPoints and AddElements read the arrays unchecked (a crash, not an error)
    coords, elements = check_mesh_arrays(scene.coords, scene.elements)
    coords = np.asarray(coords, dtype=float)
    elements = _counterclockwise(coords, np.asarray(elements, dtype=np.int32))
    ngmesh = NGMesh(dim=2)
    ngmesh.AddPoints(np.ascontiguousarray(np.column_stack([coords, np.zeros(coords.shape[0])])))
    region = ngmesh.AddRegion("omega", 2)
    ngmesh.AddElements(dim=2, index=region, data=np.ascontiguousarray(elements), base=0)
    mesh = ngs.Mesh(ngmesh)
    h1 = ngs.H1(mesh, order=1)
    l2 = ngs.L2(mesh, order=0)
    coefs, names = [], []
    for fields, space, size in ((nodal, h1, coords.shape[0]), (cellwise, l2, elements.shape[0])):
        for name, values in fields.items():
            values = np.asarray(values, dtype=float)
            if values.shape != (size,) or space.ndof != size:
                raise ValueError(f"field {name!r}: expected shape ({size},), got {values.shape}")
            gf = ngs.GridFunction(space)
            gf.vec.FV().NumPy()[:] = values
            coefs.append(gf)
            names.append(name)
    if not path.parent.is_dir():     # the caller's directory must exist: no directory is created
        raise FileNotFoundError(errno.ENOENT, f"directory {path.parent} does not exist")
    base = path.with_name(f".{path.stem[:200]}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")   # a legal name + 30 fits
    written = Path(str(base) + ".vtu")       # VTKOutput appends ".vtu" to its filename argument
    try:
        with removed_on_termination(written, base):      # SIGTERM/SIGHUP: no temporary file left either
            ngs.VTKOutput(ma=mesh, coefs=coefs, names=names, filename=str(base), subdivision=0).Do()
            data = _inline_base64(written.read_bytes())
            with open(written, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            replace_onto(written, path)
    except BaseException:
        for leftover in (written, base):
            try:
                os.unlink(leftover)
            except (FileNotFoundError, IsADirectoryError):
                pass
        raise
    return path


def solution_fields(prep, u: np.ndarray, lam: np.ndarray | None = None) -> tuple[dict, dict]:
    """The fields written for a solve: ``u`` per node, ``subdomain`` and ``body`` per element, contact data.

    Parameters
    ----------
    prep : Prepared
    u : ndarray, shape (ndof,)
        Global solution (Dirichlet nodes are 0).
    lam : ndarray, shape (n_contact,), optional
        Contact multipliers (problem contact): written as the nodal fields
        ``multiplier`` and ``gap`` (B u = u^1 - u^2, feasible where <= 0) on
        both copies of every contact node, 0 elsewhere; ``contact_node`` is 1 on
        those nodes and 0 elsewhere (where ``gap`` is not defined: NGSolve's VTK
        output turns a NaN into NaN on every cell).

    Returns
    -------
    (nodal, cellwise) : dicts of str to ndarray
    """
    from ..errors import InputError

    scene, sub = prep.scene, prep.sub
    dof = np.asarray(sub.dof_of_node)
    u = np.asarray(u, dtype=float)
    if u.shape != (sub.ndof,):
        raise InputError("u", f"must have shape ({sub.ndof},) (one value per dof), got {u.shape}")
    if lam is not None and prep.contact is not None and np.shape(lam) != (prep.contact.gi.pair_nodes.shape[0],):
        raise InputError("lam", f"must have shape ({prep.contact.gi.pair_nodes.shape[0]},) (one value per "
                                f"contact pair), got {np.shape(lam)}")
    values = np.zeros(scene.n_nodes)
    free = dof >= 0
    values[free] = u[dof[free]]
    nodal = {"u": values}
    element_sub = np.asarray(scene.element_subdomain)
    cellwise = {"subdomain": element_sub.astype(float),
                "body": np.asarray(scene.subdomain_body)[element_sub].astype(float),
                "rho": np.asarray(scene.rho, dtype=float)[element_sub]}
    if lam is not None and prep.contact is not None:
        pairs = prep.contact.gi.pair_nodes
        multiplier = np.zeros(scene.n_nodes)
        gap = np.zeros(scene.n_nodes)
        on_contact = np.zeros(scene.n_nodes)        # gap 0 off the boundary read as "in contact": this tells
        g = prep.contact.gap(np.asarray(u, dtype=float))
        for k in (0, 1):
            multiplier[pairs[:, k]] = lam
            gap[pairs[:, k]] = g
            on_contact[pairs[:, k]] = 1.0
        nodal.update(multiplier=multiplier, gap=gap, contact_node=on_contact)
    return nodal, cellwise
