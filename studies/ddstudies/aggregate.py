"""Collect many result files into one table (one row per run).

Columns are ordered: spec fields (:meth:`ProblemSpec.fields`), renamed
parameters (``param_<name>``, see :func:`ddsolve.io.hdf5.read_result`), the
scalar result keys (:data:`ddsolve.result.SCALAR_KEYS`), method-specific
extras in order of first appearance, and ``file`` (the path each row was read
from). In the CSV written by :func:`write_table`, list-valued cells (e.g.
``inner_iterations``) are space-separated integers, ``"16 16"``, like the
thesis transcriptions in ``config/thesis_tables/*.csv``; missing values are
empty cells. :func:`parse_list` turns such a cell back into a list.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import pandas as pd

from ddsolve.io.hdf5 import ResultFileError, atomic_target, validate_result


class CorruptResultsError(ResultFileError):
    """Result files that failed validation while collecting; ``paths`` lists them all."""

    def __init__(self, errors: list[ResultFileError], moved: bool):
        self.paths = [err.path for err in errors]
        self.errors = errors
        first = errors[0]
        more = f" (and {len(errors) - 1} more: {', '.join(self.paths[1:4])}{' ...' if len(errors) > 4 else ''})" \
            if len(errors) > 1 else ""
        after = "; moved aside to <file>.corrupt, the next run recomputes them" if moved else ""
        super().__init__(first.path, f"corrupt result file: {first.what}{more}{after}")


def collect(paths: Iterable[str | os.PathLike], *, quarantine: bool = False) -> pd.DataFrame:
    """Read result files into a DataFrame, one row per file, in the given order.

    Every file is validated (:func:`ddsolve.io.hdf5.validate_result`) as it is read.

    Parameters
    ----------
    paths : iterable of path-like
        Result files (:func:`ddsolve.io.hdf5.write_result`).
    quarantine : bool
        Move every corrupt file to ``<file>.corrupt`` before raising, so that the
        next workflow run recomputes it (the workflow's aggregate rules set it).

    Raises
    ------
    CorruptResultsError
        Naming the first corrupt file (after checking all of them).
    """
    rows = []
    errors: list[ResultFileError] = []
    for path in paths:
        try:
            row = validate_result(path)
        except ResultFileError as err:
            errors.append(err)
            continue
        row["file"] = os.fspath(path)
        rows.append(row)
    if errors:
        if quarantine:
            from ddstudies.workflow import quarantine as move_aside

            for err in errors:
                if os.path.exists(err.path):
                    move_aside(err.path, err.what)
        raise CorruptResultsError(errors, moved=quarantine)
    if not rows:
        return pd.DataFrame(columns=_column_order([]))
    seen: list[str] = []
    for row in rows:
        seen.extend(key for key in row if key not in seen)
    return pd.DataFrame.from_records(rows, columns=_column_order(seen))


def _column_order(seen: list[str]) -> list[str]:
    from ddsolve.result import SCALAR_KEYS
    from ddsolve.spec import ProblemSpec

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
    """Read a table written by :func:`write_table` (list cells stay strings, see :func:`parse_list`)."""
    return pd.read_csv(path)


def parse_list(cell: Any) -> list[int | float]:
    """A list cell of the summary CSV (or of a thesis transcription) as a list of numbers.

    Parameters
    ----------
    cell : str, number, list or missing
        ``"16 16"`` (the CSV form of a list-valued extra such as
        ``inner_iterations``), a single number (pandas reads a one-element list
        ``"25"`` as 25), a list (as returned by :func:`collect`), or a missing
        value (empty cell, NaN, None).

    Returns
    -------
    list of int or float
        Integers where the values are integral, else floats; ``[]`` for a
        missing value or an empty string.
    """
    if isinstance(cell, str):
        items: list[Any] = cell.split()
    elif isinstance(cell, (list, tuple, np.ndarray)):
        items = list(cell)
    elif cell is None or pd.isna(cell):
        return []
    else:
        items = [cell]
    out: list[int | float] = []
    for item in items:
        value = float(item)
        out.append(int(value) if value.is_integer() else value)
    return out
