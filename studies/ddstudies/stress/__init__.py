"""Numerical stability stress study: each case states what it proves and is judged PASS/FAIL.

- :mod:`~ddstudies.stress.catalogue`: :class:`StressCase`, :func:`catalog` (the cases of a tier),
  :func:`contact_load`;
- :mod:`~ddstudies.stress.runner`: :func:`run_case` (one case -> a flat JSON record; never raises);
- :mod:`~ddstudies.stress.criteria`: :data:`CRITERIA`, :func:`evaluate` (PASS/FAIL and a note);
- :mod:`~ddstudies.stress.render`: :func:`render_markdown` (the report), :func:`write_records`,
  :func:`read_records` (the JSON files of the Snakemake jobs).
"""
from __future__ import annotations

from .catalogue import GROUPS, HYBRID_JUMP_OPTIONS, JUMPS, StressCase, catalog, contact_load
from .criteria import CRITERIA, evaluate
from .render import read_records, render_markdown, write_records
from .runner import run_case

__all__ = ["CRITERIA", "GROUPS", "HYBRID_JUMP_OPTIONS", "JUMPS", "StressCase", "catalog", "contact_load", "evaluate",
           "read_records", "render_markdown", "run_case", "write_records"]
