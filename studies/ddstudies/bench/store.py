"""Benchmark files: the reference of a problem and one file per case.

Case files use the project's result layout (:func:`ddsolve.io.hdf5.write_result`,
README "HDF5 layout"): ``/params`` holds the problem spec with ``method`` the
benchmarked method and ``rtol`` the case's tolerance (NaN for direct
solvers), plus ``repeats``; ``/result`` holds the scalars of
:class:`~ddstudies.bench.case.CaseRecord`. They are read back with
:func:`ddsolve.io.hdf5.read_result` and collected with
:func:`ddstudies.aggregate.collect`.

Reference files (``format = "ddsolve-bench-reference"``, version 1) hold the
spec as root attributes ``spec_<field>``, the scalars ``energy_fine``,
``discretization_error`` and the :attr:`Reference.info` entries, and the
datasets ``u_direct``, ``g_fine`` and one ``vector_<name>`` per entry of
:attr:`Reference.vectors` (e.g. ``vector_lambda`` for contact); both writers
are atomic.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import h5py
import numpy as np

from ddsolve.io.hdf5 import _fsync, atomic_target, write_result

from .case import CaseRecord, Reference
from .refine import FineReference

REFERENCE_FORMAT = "ddsolve-bench-reference"
REFERENCE_VERSION = 1


def write_reference(path: str | os.PathLike, spec: Mapping[str, Any], ref: Reference) -> Path:
    """Write ``ref`` (of the problem ``spec``) to ``path`` atomically."""
    path = Path(path)
    with atomic_target(path) as tmp:
        with h5py.File(tmp, "x") as h5:
            h5.attrs["format"] = REFERENCE_FORMAT
            h5.attrs["format_version"] = np.int64(REFERENCE_VERSION)
            for key, val in spec.items():
                h5.attrs[f"spec_{key}"] = np.nan if val is None else val
            h5.attrs["energy_fine"] = ref.fine.energy
            h5.attrs["discretization_error"] = ref.discretization_error
            for key, val in ref.info.items():
                h5.attrs[key] = val
            h5.create_dataset("u_direct", data=np.asarray(ref.u_direct, dtype=np.float64))
            h5.create_dataset("g_fine", data=np.asarray(ref.fine.g, dtype=np.float64))
            for key, vec in ref.vectors.items():
                h5.create_dataset(f"vector_{key}", data=np.asarray(vec, dtype=np.float64))
        _fsync(tmp)
    return path


def read_reference(path: str | os.PathLike) -> Reference:
    """Read a file of :func:`write_reference`.

    Raises
    ------
    ValueError
        Not a benchmark reference file.
    """
    with h5py.File(path, "r") as h5:
        if h5.attrs.get("format") != REFERENCE_FORMAT:
            raise ValueError(f"{os.fspath(path)}: not a benchmark reference file")
        skip = {"format", "format_version", "energy_fine", "discretization_error"}
        info = {k: v.item() if hasattr(v, "item") else v for k, v in h5.attrs.items()
                if k not in skip and not k.startswith("spec_")}
        vectors = {name[len("vector_"):]: np.asarray(h5[name][()]) for name in h5 if name.startswith("vector_")}
        return Reference(u_direct=np.asarray(h5["u_direct"][()]),
                         fine=FineReference(energy=float(h5.attrs["energy_fine"]), g=np.asarray(h5["g_fine"][()])),
                         discretization_error=float(h5.attrs["discretization_error"]), info=info,
                         vectors=vectors)


def write_case(path: str | os.PathLike, spec: Mapping[str, Any], method: str, rtol: float | None,
               record: CaseRecord, repeats: int) -> Path:
    """Write one case (``spec`` is the problem's ProblemSpec mapping) with :func:`write_result`."""
    params = {**dict(spec), "method": method, "rtol": rtol, "repeats": int(repeats)}
    return write_result(path, params, record)
