"""Stress study, rendering: the Markdown report (:func:`render_markdown`) and the JSON record files."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..report.rule_sets import DEFAULT, NOTE_MARK, only_sentence
from .catalogue import GROUPS
from .criteria import CRITERIA

__all__ = ["render_markdown", "write_records", "read_records"]


def _num(value: Any, fmt: str = ".1e") -> str:
    return "–" if value is None else format(value, fmt)


def _markdown_cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def render_markdown(rows: Sequence[Mapping[str, Any]], *, title: str = "Numerical stability stress tests") -> str:
    """The report: a summary, the criteria, then one table per group with one row per case.

    Parameters
    ----------
    rows : sequence of dict
        Output of :func:`evaluate`.
    title : str

    Returns
    -------
    str
        Markdown text.
    """
    n_fail = sum(r["outcome"] == "FAIL" for r in rows)
    lines = [f"# {title}", "",
             f"{len(rows)} cases: {len(rows) - n_fail} PASS, {n_fail} FAIL.", "",
             f"{NOTE_MARK} {only_sentence(DEFAULT)}", "",
             "Columns: *iter* = Krylov iterations (contact: all inner iterations); *cond* = Lanczos "
             "estimate (PCG methods only); *true* / *rec.* = residual recomputed from the final iterate / "
             "recursively updated residual, both relative to ||r_0|| (contact: *true* is the relative KKT "
             "residual (5.5) of (u, lambda), *rec.* SMALBE's final ||g^P|| / ||b||); *err* = relative "
             "energy-norm error against the direct solver (contact: relative l2 error of u); *outcome* "
             "against the row's criterion.", "", "Criteria:", ""]
    lines += [f"- `{key}`: {text}" for key, (text, _) in CRITERIA.items()]
    for group, heading in GROUPS.items():
        part = [r for r in rows if r["group"] == group]
        if not part:
            continue
        fails = sum(r["outcome"] == "FAIL" for r in part)
        lines += ["", f"## {heading}", "", f"{len(part)} cases, {fails} FAIL.", "",
                  "| case | what it proves | iter | cond | true | rec. | err | criterion | outcome | note |",
                  "|---|---|---:|---:|---:|---:|---:|---|---|---|"]
        for r in part:
            contact = r["spec"].get("problem") == "contact" and r["runner"] == "contact"
            true = r.get("kkt") if contact else r["true_rel"]
            rec = r.get("smalbe_gradient") if contact else r["rec_rel"]
            it = "–" if r["iterations"] is None else str(r["iterations"])
            if not r["converged"] and r["status"] == "ok":
                it += "*"
            cells = [f"`{r['name']}`", r["claim"], it, _num(r["cond"], ".3g"), _num(true), _num(rec),
                     _num(r["error_vs_direct"]), f"`{r['criterion']}`", f"**{r['outcome']}**", r["note"]]
            lines.append("| " + " | ".join(_markdown_cell(c) for c in cells) + " |")
    lines += ["", "`*`: not converged (the reason is in the note or in the case's record).", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------- #
# Files
# --------------------------------------------------------------------------- #
def write_records(path: str | os.PathLike, records: Sequence[Mapping[str, Any]]) -> Path:
    """Write records as one JSON list, atomically (temporary file, then rename)."""
    from ddsolve.io.hdf5 import atomic_target

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_target(path) as tmp:
        tmp.write_text(json.dumps(list(records), indent=1, allow_nan=False) + "\n")
    return path


def read_records(paths: Sequence[str | os.PathLike]) -> list[dict[str, Any]]:
    """Concatenate the record lists of several files, in order."""
    from ..workflow import read_job_results

    out: list[dict[str, Any]] = []
    for records in read_job_results(paths):      # checked: a corrupt file is moved aside and named
        out += records
    return out
