"""Collect many result files into one table (one row per run).

Columns are ordered: spec fields (:meth:`ProblemSpec.fields`), renamed
parameters (``param_<name>``, see :func:`ddsolve.io.hdf5.read_result`), the
scalar result keys (:data:`ddsolve.result.SCALAR_KEYS`), method-specific
extras in order of first appearance, and ``file`` (the path each row was read
from). In the CSV written by :func:`write_table`, list-valued cells (e.g.
``inner_iterations``) are space-separated integers, ``"16 16"``, like the
thesis transcriptions in ``tables/*.csv``; missing values are empty cells.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

import pandas as pd

from .hdf5 import atomic_target, read_result


def collect(paths: Iterable[str | os.PathLike]) -> pd.DataFrame:
    """Read result files into a DataFrame, one row per file, in the given order."""
    rows = []
    for path in paths:
        row = read_result(path)
        row["file"] = os.fspath(path)
        rows.append(row)
    if not rows:
        return pd.DataFrame(columns=_column_order([]))
    seen: list[str] = []
    for row in rows:
        seen.extend(key for key in row if key not in seen)
    return pd.DataFrame.from_records(rows, columns=_column_order(seen))


def _column_order(seen: list[str]) -> list[str]:
    from ..result import SCALAR_KEYS
    from ..spec import ProblemSpec

    columns: list[str] = []
    for key in ProblemSpec.fields():  # parameters, in spec order
        if f"param_{key}" in seen:
            columns.append(f"param_{key}")
        elif key in seen:
            columns.append(key)
    columns += [key for key in SCALAR_KEYS if key in seen and key not in columns]
    columns += [key for key in seen if key not in columns and key != "file"]
    return columns + ["file"]


def _cell_to_csv(value):
    if isinstance(value, (list, tuple)):
        return " ".join(str(v) for v in value)
    return value


def write_table(df: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Write ``df`` as CSV (no index), atomically; readable with :func:`pandas.read_csv`."""
    path = Path(path)
    out = df.copy()
    for col in out.columns:
        if out[col].dtype == object:
            out[col] = out[col].map(_cell_to_csv)
    with atomic_target(path) as tmp:
        out.to_csv(tmp, index=False)
    return path


def read_table(path: str | os.PathLike) -> pd.DataFrame:
    """Read a table written by :func:`write_table` (list cells stay strings)."""
    return pd.read_csv(path)
