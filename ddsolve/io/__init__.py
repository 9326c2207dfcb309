"""Result files.

- :mod:`ddsolve.io.hdf5`: one run per HDF5 file (:func:`write_result`,
  :func:`read_result`, :func:`read_residuals`); layout in docs/hdf5.md.
- :mod:`ddsolve.io.joblog`: a Snakemake job's output into its log file.

Many runs into one DataFrame / CSV is :mod:`ddstudies.aggregate` (the study
package; it needs pandas). Names are imported lazily.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "write_result": "hdf5",
    "read_result": "hdf5",
    "read_residuals": "hdf5",
    "read_params": "hdf5",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        module = importlib.import_module(f".{_EXPORTS[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
