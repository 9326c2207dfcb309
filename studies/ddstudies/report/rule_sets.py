"""Thesis tables with both rule sets: ddsolve's defaults and a preset (e.g. the thesis's literal rules).

A study that sweeps ``preset`` (the :class:`ddsolve.spec.ProblemSpec` field of
branch ``preset``; column :data:`RULE_SET_COLUMN` of the summary CSV) has runs
of the same case under several rule sets. :func:`by_rule_set` builds a table
per rule set with the table's own builder (:func:`~ddstudies.report.tables.multibody_table`,
:func:`~ddstudies.report.contact_tables.contact_table`) and pairs their rows:
each case appears once per rule set, the rule set named in the last index
level. :func:`closer_sentence` is the computed note under the table: whether a
preset is closer to the thesis than the defaults (comparing the tables'
relative deviation columns value by value), or that neither reproduces it.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd

__all__ = ["DEFAULT", "RULE_SET_COLUMN", "RULE_SET_LEVEL", "by_rule_set", "closer_sentence", "one_rule_set",
           "only_sentence", "chosen_rule_set",
           "rule_sets"]

#: column of the aggregated runs naming the rule set (the spec's ``preset``)
RULE_SET_COLUMN = "preset"
#: the rule set of runs without a preset
DEFAULT = "default"
#: index level of the paired rows
RULE_SET_LEVEL = "rules"
#: relative deviation below which a value counts as reproduced
MATCH = 0.01
#: difference of two relative deviations below which they count as equal (0.1 percentage
#: point, the precision the tables print them with): a Lanczos estimate differing in its
#: fifth digit makes neither rule set closer
TIE = 1e-3
#: the note's mark (a key of ``attrs["notes"]``)
NOTE_MARK = "Rule sets:"


def rule_sets(df: pd.DataFrame) -> list[str]:
    """Rule sets present in ``df``: ``"default"`` first, then the others sorted; ``["default"]`` without the column."""
    if RULE_SET_COLUMN not in df.columns:
        return [DEFAULT]
    names = {DEFAULT if pd.isna(v) or v in ("", None) else str(v) for v in df[RULE_SET_COLUMN]}
    return sorted(names, key=lambda n: (n != DEFAULT, n)) or [DEFAULT]


def only_sentence(name: str) -> str:
    """The note of a table or figure whose every number comes from the one rule set ``name``."""
    return f"every number here is from rule set {name!r} (ddsolve.presets), the only one this study ran."


def chosen_rule_set(df: pd.DataFrame, name: str = DEFAULT) -> str:
    """The rule set whose runs :func:`one_rule_set` returns for ``name``."""
    ran = rule_sets(df)
    return ran[0] if name == DEFAULT and DEFAULT not in ran and len(ran) == 1 else name


def one_rule_set(df: pd.DataFrame, name: str = DEFAULT) -> pd.DataFrame:
    """The runs of one rule set, without the column :data:`RULE_SET_COLUMN`.

    For the reports that show one run per case (figures, the growth table, the
    contact comparison): a study sweeping ``presets`` has several runs per case,
    and these reports must not mix them. ``df`` without the column is returned
    unchanged (all its runs are the defaults'). A study that ran one other
    rule set only (``preset: thesis``) gives its runs for ``name`` = default;
    the caller names it (:func:`rule_sets`).

    Raises
    ------
    ValueError
        If ``df`` has runs but none of rule set ``name`` (and more than one other).
    """
    if RULE_SET_COLUMN not in df.columns:
        return df
    name = chosen_rule_set(df, name)
    out = _select(df, name)
    if out.empty and not df.empty:
        raise ValueError(f"one_rule_set: no run of rule set {name!r} (have: {', '.join(rule_sets(df))})")
    return out


def _select(df: pd.DataFrame, name: str) -> pd.DataFrame:
    col = df[RULE_SET_COLUMN].where(df[RULE_SET_COLUMN].notna() & (df[RULE_SET_COLUMN] != ""), DEFAULT)
    return df[col.astype(str) == name].drop(columns=RULE_SET_COLUMN)


def _dev_columns(table: pd.DataFrame) -> list[Any]:
    return [c for c in table.columns
            if str(c[-1] if isinstance(c, tuple) else c).endswith("dev")]


def closer_sentence(tables: Mapping[str, pd.DataFrame], *, tried: str = "docs/findings.md") -> str:
    """Computed note: is a preset closer to the thesis than the defaults?

    Compares, for every value with a deviation from the thesis in both tables
    (the columns whose last label ends in ``dev``, on the rows both have),
    ``|dev|`` of each preset with that of the defaults.

    Parameters
    ----------
    tables : mapping rule set -> table
        The per-rule-set tables, ``"default"`` among them.
    tried : str
        Where the readings tried are documented (named when neither rule set
        reproduces the thesis).
    """
    if DEFAULT not in tables or len(tables) < 2:
        return "Only one rule set ran; nothing to compare."
    base = tables[DEFAULT]
    parts = []
    reproduced_any = False
    for name, table in tables.items():
        if name == DEFAULT:
            continue
        cols = [c for c in _dev_columns(base) if c in table.columns]
        rows = base.index.intersection(table.index)
        if not cols or rows.empty:
            parts.append(f"{name}: no value to compare with the thesis")
            continue
        a = np.abs(base.loc[rows, cols].apply(pd.to_numeric, errors="coerce").to_numpy(float)).ravel()
        b = np.abs(table.loc[rows, cols].apply(pd.to_numeric, errors="coerce").to_numpy(float)).ravel()
        ok = np.isfinite(a) & np.isfinite(b)
        a, b = a[ok], b[ok]
        if not a.size:
            parts.append(f"{name}: no value to compare with the thesis")
            continue
        closer, farther = int(np.sum(b < a - TIE)), int(np.sum(b > a + TIE))
        matched = int(np.sum(b <= MATCH)), int(np.sum(a <= MATCH))
        reproduced_any |= bool(matched[0] or matched[1])
        verdict = ("closer to the thesis than the defaults" if b.mean() < a.mean() - TIE else
                   "as close to the thesis as the defaults (not closer)" if b.mean() <= a.mean() + TIE else
                   "not closer to the thesis than the defaults")
        parts.append(f"preset {name} is {verdict} (closer in {closer}, farther in {farther} of {a.size} "
                     f"compared values; mean |dev| {b.mean():.1%} against {a.mean():.1%}; within "
                     f"{MATCH:.0%} of the thesis: {matched[0]} ({name}) and {matched[1]} (default))")
    text = "; ".join(parts) + "."
    if not reproduced_any:
        text += f" Neither rule set reproduces a printed value within {MATCH:.0%}; what was tried: {tried}."
    return text


def by_rule_set(df: pd.DataFrame, build: Callable[[pd.DataFrame], pd.DataFrame], *,
                tried: str = "docs/findings.md") -> pd.DataFrame:
    """``build(df)``, or with several rule sets in ``df`` their tables with paired rows.

    Parameters
    ----------
    df : DataFrame
        Aggregated runs, optionally with the column :data:`RULE_SET_COLUMN`.
    build : callable
        DataFrame of one rule set's runs (without that column) -> table.

    Returns
    -------
    DataFrame
        With one rule set: ``build``'s table unchanged. Otherwise the tables
        stacked with the rule set as the last index level (named
        :data:`RULE_SET_LEVEL`), rows ordered as the default table's (each
        case followed by its other rule sets), ``attrs["marks"]`` re-keyed and
        ``attrs["notes"]`` with the computed :func:`closer_sentence`.
    """
    names = rule_sets(df)
    if len(names) == 1:
        table = build(df.drop(columns=RULE_SET_COLUMN) if RULE_SET_COLUMN in df.columns else df)
        if names[0] != DEFAULT:         # a study of one other preset: say whose numbers these are
            table.attrs["notes"] = {**table.attrs.get("notes", {}), NOTE_MARK: only_sentence(names[0])}
        return table
    tables = {name: build(_select(df, name)) for name in names}
    order: list[Any] = []
    for table in tables.values():
        order += [k for k in table.index if k not in order]
    pieces, marks, notes = [], [], {}
    for name, table in tables.items():
        keys = [(k if isinstance(k, tuple) else (k,)) + (name,) for k in table.index]
        piece = table.copy()
        piece.index = pd.MultiIndex.from_tuples(keys, names=[*table.index.names, RULE_SET_LEVEL])
        pieces.append(piece)
        for key, col, mark in table.attrs.get("marks", []):
            marks.append(((key if isinstance(key, tuple) else (key,)) + (name,), col, mark))
        notes.update(table.attrs.get("notes", {}))
    out = pd.concat(pieces)
    rank = {(k if isinstance(k, tuple) else (k,)): i for i, k in enumerate(order)}
    position = [(rank[k[:-1]], names.index(k[-1])) for k in out.index]
    out = out.iloc[sorted(range(len(out)), key=position.__getitem__)]
    out.attrs["marks"] = marks
    notes[NOTE_MARK] = closer_sentence(tables, tried=tried)
    out.attrs["notes"] = notes
    return out
