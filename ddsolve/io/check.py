"""Cheap checks of result files that need neither numpy nor h5py (the workflow runs them while planning).

:func:`quick_check` reads the HDF5 superblock (HDF5 file format specification,
section "Disk Format: Level 0A - Format Signature and Superblock", versions
0-3) and compares its end-of-file address with the size of the file; a file
cut short by a full disk, a killed copy or a crash is shorter than that.
"""
from __future__ import annotations

import os
import struct

__all__ = ["quick_check"]

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def quick_check(path: str | os.PathLike) -> str | None:
    """A cheap check of an HDF5 file without h5py: None if it looks whole, else what is wrong.

    Reads the superblock (HDF5 file format specification, versions 0-3) and
    compares its end-of-file address with the file size: a truncated file is
    shorter. Used by the workflow on every existing result before planning;
    :func:`ddsolve.io.hdf5.validate_result` is the full check.
    """
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            head = fh.read(128)
    except FileNotFoundError:
        return "no such result file"
    except OSError as exc:
        return f"cannot read ({exc.strerror or exc})"
    if size == 0:
        return "empty file"
    if not head.startswith(_HDF5_SIGNATURE):
        return "not an HDF5 file (no HDF5 signature at offset 0)"
    eof = _superblock_eof(head)
    if eof is None:
        return "truncated or corrupt HDF5 superblock"
    if size < eof:
        return f"truncated: {size} bytes, the HDF5 superblock says {eof}"
    return None


def _superblock_eof(head: bytes) -> int | None:
    """End-of-file address of an HDF5 superblock at offset 0 (None if it cannot be read)."""
    if len(head) < 12:
        return None
    version = head[8]
    if version in (0, 1):
        if len(head) < 24:
            return None
        offsets = head[13]
        start = 24 + (4 if version == 1 else 0)
        index = 2           # base address, free-space info address, end of file address
    elif version in (2, 3):
        offsets = head[9]
        start = 12
        index = 2           # base address, superblock extension address, end of file address
    else:
        return None
    fmt = {4: "<I", 8: "<Q"}.get(offsets)
    pos = start + index * offsets
    if fmt is None or len(head) < pos + offsets:
        return None
    return struct.unpack_from(fmt, head, pos)[0]
