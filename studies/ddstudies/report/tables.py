"""Thesis-style tables from the aggregated results (see :mod:`ddstudies.aggregate`).

The main table, :func:`condition_table`, has one row per (1/H, H/h) case and,
per method, the columns ``cond`` (Lanczos condition number estimate) and
``iter`` (Krylov iterations), like Table 4.1 of the thesis. It is a DataFrame
with a column MultiIndex ``(method, quantity)``; :func:`to_markdown` and
:func:`to_latex` render it (or any flat DataFrame) as text. Iteration counts
of runs that did not converge are marked ``*`` with a note under the table.

Comparisons with the thesis use flat frames: :func:`flatten` turns the wide
table into columns ``<method>_<quantity>``, and :func:`side_by_side` merges our
values with a transcribed thesis table (``tables/table_4_1.csv``, ...) on key
columns, adding ``<col>_thesis`` and ``<col>_dev`` = (ours - thesis) / |thesis|.

Multibody studies (problem (4.32)) are shown like Tables 4.1 / 4.2 by
:func:`multibody_table`: rows (1/H_b, H_b/H_s, H_s/h), one column group per
contact case ((I) = ``full``, (II) = ``middle``), and beside each of our values
the thesis's value and the relative deviation. Rows beyond the thesis's table
(no thesis value) can be marked with :func:`mark_beyond_thesis`;
:func:`hbhs_sweep_table` shows both methods along the H_b/H_s sweep and
:func:`growth_table` renders the fits of :func:`ddstudies.report.plots.hbhs_growth`.
"""
from __future__ import annotations

import math
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

from .fits import r2_text
from .rule_sets import DEFAULT, RULE_SET_COLUMN, by_rule_set, chosen_rule_set, one_rule_set, only_sentence

#: Display names of key columns (1/H = subdomains per side, H/h = elements per subdomain side).
ROW_LABELS: dict[str, str] = {
    "bodies": "1/H_b",
    "subdomains": "1/H",
    "elements": "H/h",
    "rules": "rule set",     # ddstudies.report.rule_sets.RULE_SET_LEVEL: paired rows per preset
}
#: LaTeX versions of labels that need math mode.
LATEX_LABELS: dict[str, str] = {
    "1/H_b": "$1/H_b$",
    "1/H": "$1/H$",
    "H/h": "$H/h$",
    "H_b/H_s": "$H_b/H_s$",
    "H_s/h": "$H_s/h$",
}
METHOD_LABELS: dict[str, str] = {
    "feti": "FETI",
    "fetidp": "FETI-DP",
    "bddc": "BDDC",
    "direct": "direct",
    "feti-feti": "FETI-FETI",
    "hybrid": "hybrid",
}
QUANTITY_LABELS: dict[str, str] = {
    "cond": "cond",
    "iterations": "iter",
    "thesis": "thesis",
    "dev": "dev.",
    "cond_thesis": "cond thesis",
    "cond_dev": "cond dev.",
    "iterations_thesis": "iter thesis",
    "iterations_dev": "iter dev.",
}
#: Quantities shown as integers even when missing values made them float.
INTEGER_QUANTITIES = frozenset({"iterations", "ndof", "nlambda", "n_factorizations",
                                "subdomains", "elements", "bodies"})
NOT_CONVERGED_MARK = "*"
NOT_CONVERGED_NOTE = "not converged (stopped at maxiter or by a breakdown); the count is where it stopped"

#: Contact areas of problem (4.32) and the thesis's names of the two cases.
CONTACT_CASES: dict[str, str] = {"full": "I", "middle": "II"}
#: Our key columns of a multibody case -> the keys of the thesis transcriptions
#: (``tables/table_4_1.csv``, ``tables/table_4_2.csv``).
THESIS_KEYS: dict[str, str] = {"bodies": "inv_Hb", "subdomains": "Hb_over_Hs", "elements": "Hs_over_h"}
#: Our quantities -> their prefix in the thesis transcriptions (``cond_I``, ``iter_II``).
THESIS_QUANTITIES: dict[str, str] = {"cond": "cond", "iterations": "iter"}
#: Display names of the multibody keys (the thesis's notation).
MULTIBODY_ROW_LABELS: dict[str, str] = {"bodies": "1/H_b", "subdomains": "H_b/H_s", "elements": "H_s/h"}

#: Parameters summarised by :func:`describe_constants`, in this order.
DESCRIBED_PARAMS: tuple[str, ...] = ("problem", "bodies", "rho", "f", "scaling", "gamma", "rtol", "maxiter")


# ----------------------------------------------------------------------------
# building tables
# ----------------------------------------------------------------------------

def _truthy(value: Any) -> bool:
    """A flag of a results table, also read back from CSV text ("True", "1", "1.0", "yes")."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    return str(value).strip().lower() in ("true", "1", "1.0", "yes")


def condition_table(df: pd.DataFrame, *, rows: Sequence[str] = ("subdomains", "elements"),
                    methods: Sequence[str] | None = None,
                    quantities: Sequence[str] = ("cond", "iterations")) -> pd.DataFrame:
    """Pivot the aggregated runs into the thesis layout.

    Parameters
    ----------
    df : DataFrame
        One row per run (:func:`ddstudies.aggregate.collect` or the summary CSV),
        with columns ``method``, the ``rows`` keys and the ``quantities``.
    rows : sequence of str
        Key columns that identify a row, default (1/H, H/h) = (subdomains, elements).
    methods : sequence of str, optional
        Methods (column groups) in display order; default: order of appearance.
        A method without runs gets empty columns.
    quantities : sequence of str
        Values shown per method, default (cond, iterations).

    Returns
    -------
    DataFrame
        Index: the ``rows`` keys (sorted); columns: MultiIndex (method, quantity).
        ``attrs["marks"]`` lists ``(index, column, mark)`` of flagged cells and
        ``attrs["notes"]`` maps a mark to its footnote.

    Raises
    ------
    KeyError
        If a needed column is missing.
    ValueError
        If two runs share the same method and row keys.
    """
    rows = list(rows)
    quantities = list(quantities)
    missing = [c for c in ["method", *rows, *quantities] if c not in df.columns]
    if missing:
        raise KeyError(f"condition_table: missing column(s) {', '.join(missing)}")
    data = df.copy()
    if methods is None:
        methods = list(dict.fromkeys(data["method"]))
    else:
        methods = list(methods)
        data = data[data["method"].isin(methods)]
    dup = data.duplicated(subset=[*rows, "method"], keep=False)
    if dup.any():
        cases = data.loc[dup, ["method", *rows]].drop_duplicates().to_dict("records")
        raise ValueError(f"condition_table: several runs for the same case: {cases}")
    for q in quantities:
        data[q] = pd.to_numeric(data[q], errors="coerce")
    columns = pd.MultiIndex.from_product([methods, quantities], names=["method", "quantity"])
    if data.empty:
        index = pd.MultiIndex.from_tuples([], names=rows) if len(rows) > 1 else pd.Index([], name=rows[0])
        wide = pd.DataFrame(index=index, columns=columns, dtype=float)
    else:
        wide = data.pivot(index=rows, columns="method", values=quantities)
        wide = wide.swaplevel(0, 1, axis=1).reindex(columns=columns).sort_index()
    wide.columns.names = ["method", "quantity"]
    for col in wide.columns:
        if col[1] in INTEGER_QUANTITIES or pd.api.types.is_integer_dtype(df[col[1]].dtype):
            values = pd.to_numeric(wide[col], errors="coerce")
            if values.dropna().map(lambda v: float(v).is_integer()).all():
                wide[col] = values.round().astype("Int64")

    marks = []
    if "converged" in data.columns and not data.empty:
        flag_q = "iterations" if "iterations" in quantities else quantities[0]
        for _, run in data.iterrows():
            if not _truthy(run["converged"]):
                key = tuple(run[r] for r in rows) if len(rows) > 1 else run[rows[0]]
                marks.append((key, (run["method"], flag_q), NOT_CONVERGED_MARK))
    wide.attrs["marks"] = marks
    wide.attrs["notes"] = {NOT_CONVERGED_MARK: NOT_CONVERGED_NOTE} if marks else {}
    return wide


def label_presets(df: pd.DataFrame, methods: Sequence[str] | None = None) -> tuple[pd.DataFrame, list[str] | None]:
    """A summary of several rule sets: each (method, preset) becomes its own method label ``"method [preset]"``.

    A grid study with ``presets: [default, thesis]`` solves every case once per rule set; without this
    the table refused the pairs (several runs for the same case) and the plot fitted both as one.
    With one preset (or no ``preset`` column) ``df`` and ``methods`` come back unchanged, except that
    the one preset of a study that ran another than the default (``preset: thesis``) is named too.

    Returns
    -------
    df : DataFrame
    methods : list of str or None
        The labels in display order: each method's presets together, in order of appearance.
    """
    single = "preset" in df.columns and df["preset"].nunique(dropna=False) == 1
    if "preset" not in df.columns or (single and str(df["preset"].iloc[0]) in ("", "nan", DEFAULT)):
        return df, (list(methods) if methods is not None else None)
    presets = list(dict.fromkeys(df["preset"].astype(str)))
    out = df.copy()
    out["method"] = out["method"].astype(str) + " [" + out["preset"].astype(str) + "]"
    names = list(methods) if methods is not None else list(dict.fromkeys(df["method"].astype(str)))
    return out, [f"{m} [{p}]" for m in names for p in presets]


def flatten(table: pd.DataFrame, sep: str = "_") -> pd.DataFrame:
    """Wide table -> flat frame: index as columns, ``(method, q)`` as ``method<sep>q``."""
    out = table.copy()
    if isinstance(out.columns, pd.MultiIndex):
        out.columns = [sep.join(str(p) for p in col if str(p)) for col in out.columns]
    if out.index.names != [None]:
        out = out.reset_index()
    out.attrs = {}
    return out


def side_by_side(ours_df: pd.DataFrame, thesis_df: pd.DataFrame,
                 keys: Sequence[str] | Mapping[str, str],
                 columns: Sequence[str] | Mapping[str, str], *, how: str = "left") -> pd.DataFrame:
    """Put our values beside the thesis's and their relative deviation.

    Parameters
    ----------
    ours_df, thesis_df : DataFrame
        Flat frames (use :func:`flatten` on a wide table).
    keys : list of str or mapping
        Key columns to merge on. A list names columns present in both frames; a
        mapping ``{ours_name: thesis_name}`` renames the thesis's keys (e.g.
        ``{"elements": "Hs_over_h"}``).
    columns : list of str or mapping
        Compared value columns, likewise ``{ours_name: thesis_name}`` (e.g.
        ``{"feti_cond": "cond_I"}``).
    how : str
        Merge type (``"left"``: all our rows, NaN where the thesis has none;
        ``"inner"``: only rows in both).

    Returns
    -------
    DataFrame
        The key columns, then for each value column ``<col>``, ``<col>_thesis``,
        ``<col>_dev`` with ``dev = (ours - thesis) / |thesis|`` (NaN where either
        is missing or not numeric, or the thesis value is 0).
    """
    kmap = dict(keys) if isinstance(keys, Mapping) else {k: k for k in keys}
    cmap = dict(columns) if isinstance(columns, Mapping) else {c: c for c in columns}
    for name, frame, cols in (("ours_df", ours_df, list(kmap) + list(cmap)),
                              ("thesis_df", thesis_df, list(kmap.values()) + list(cmap.values()))):
        missing = [c for c in cols if c not in frame.columns]
        if missing:
            raise KeyError(f"side_by_side: {name} lacks column(s) {', '.join(missing)}")
    ours = ours_df[list(kmap) + list(cmap)].copy()
    ours.attrs = {}
    thesis = thesis_df[list(kmap.values()) + list(cmap.values())].copy()
    thesis.attrs = {}
    thesis.columns = list(kmap) + [f"{c}_thesis" for c in cmap]
    merged = ours.merge(thesis, on=list(kmap), how=how)
    out_cols = list(kmap)
    for col in cmap:
        mine = pd.to_numeric(merged[col], errors="coerce").astype(float)
        ref = pd.to_numeric(merged[f"{col}_thesis"], errors="coerce").astype(float)
        dev = (mine - ref) / ref.abs()
        merged[f"{col}_dev"] = dev.where(ref != 0)
        out_cols += [col, f"{col}_thesis", f"{col}_dev"]
    return merged[out_cols]


def multibody_table(df: pd.DataFrame, thesis: pd.DataFrame | None = None, *, method: str,
                    quantities: Sequence[str] = ("cond", "iterations"),
                    contacts: Sequence[str] = ("full", "middle"),
                    order: Sequence[Sequence[int]] | None = None) -> pd.DataFrame:
    """One method's multibody runs in the layout of Tables 4.1 / 4.2, beside the thesis.

    Parameters
    ----------
    df : DataFrame
        Aggregated runs with columns ``method``, ``contact``, ``bodies``,
        ``subdomains``, ``elements`` and the ``quantities`` (and optionally
        ``converged``).
    thesis : DataFrame, optional
        A thesis transcription with the keys of :data:`THESIS_KEYS` and the
        columns ``<cond|iter>_<I|II>`` (:data:`THESIS_QUANTITIES`). A quantity
        the transcription lacks gets no comparison columns. Without it, only
        our values are shown.
    method : str
        The method shown (e.g. ``"feti-feti"``).
    quantities : sequence of str
        Our quantities per case, default (cond, iterations).
    contacts : sequence of str
        Contact areas, one column group each: ``"full"`` -> (I), ``"middle"`` -> (II).
    order : sequence of (bodies, subdomains, elements), optional
        Row order (e.g. the study's cases); rows not listed follow, sorted.
        Default: the thesis's row order, else sorted.

    Returns
    -------
    DataFrame
        Index (1/H_b, H_b/H_s, H_s/h) with our cases only; columns a MultiIndex
        ``("(I)", q)``, ``("(I)", q + "_thesis")``, ``("(I)", q + "_dev")``, ...
        with dev = (ours - thesis) / |thesis| (:func:`side_by_side`). Iteration
        counts of runs that did not converge are marked as in
        :func:`condition_table`. Render with :func:`to_markdown` / :func:`to_latex`.

    Raises
    ------
    KeyError
        If a needed column is missing or a contact is unknown.
    ValueError
        If two runs share method, contact and keys.
    """
    if RULE_SET_COLUMN in df.columns:    # several rule sets (the spec's preset): paired rows
        return by_rule_set(df, lambda runs: multibody_table(runs, thesis, method=method, quantities=quantities,
                                                            contacts=contacts, order=order))
    keys = list(THESIS_KEYS)
    quantities = list(quantities)
    unknown = [c for c in contacts if c not in CONTACT_CASES]
    if unknown:
        raise KeyError(f"multibody_table: unknown contact(s) {', '.join(unknown)}")
    if "contact" not in df.columns:
        raise KeyError("multibody_table: missing column contact")
    cases = [CONTACT_CASES[c] for c in contacts]
    data = df[(df["method"] == method) & df["contact"].isin(list(contacts))].copy()
    data["method"] = data["contact"].map(CONTACT_CASES)  # the case plays the method's role
    wide = condition_table(data.astype({"method": object}), rows=keys, methods=cases,
                           quantities=quantities)
    marks, notes = wide.attrs["marks"], wide.attrs["notes"]
    flat = flatten(wide)
    for key in keys:
        flat[key] = pd.to_numeric(flat[key]).astype("int64")

    if order is None and thesis is not None:
        order = thesis[list(THESIS_KEYS.values())].itertuples(index=False, name=None)
    rank = {tuple(int(v) for v in case): i for i, case in enumerate(order or [])}
    position = [rank.get(tuple(row), len(rank)) for row in flat[keys].itertuples(index=False, name=None)]
    flat = flat.assign(_rank=position).sort_values(["_rank", *keys], kind="stable")
    flat = flat.drop(columns="_rank").reset_index(drop=True)

    compared = {}
    if thesis is not None:
        for case in cases:
            for q in quantities:
                name = f"{THESIS_QUANTITIES.get(q, q)}_{case}"
                if name in thesis.columns:
                    compared[f"{case}_{q}"] = name
    merged = flat
    if compared:
        merged = side_by_side(flat, thesis, keys=THESIS_KEYS, columns=compared)
        if len(merged) != len(flat):
            raise ValueError("multibody_table: the thesis table lists a case more than once")
        for col in flat.columns.difference(merged.columns):
            merged[col] = flat[col].to_numpy()

    columns, sources = [], []
    for case in cases:
        for q in quantities:
            source = f"{case}_{q}"
            suffixes = ["", "_thesis", "_dev"] if source in compared else [""]
            for suffix in suffixes:
                columns.append((f"({case})", q + suffix))
                sources.append(source + suffix)
    out = merged[sources].copy()
    out.columns = pd.MultiIndex.from_tuples(columns, names=["case", "quantity"])
    out.index = pd.MultiIndex.from_frame(merged[keys].rename(columns=MULTIBODY_ROW_LABELS))
    for col in out.columns:
        if col[1].startswith("iterations") and not col[1].endswith("_dev"):
            values = pd.to_numeric(out[col], errors="coerce")
            if values.dropna().map(lambda v: float(v).is_integer()).all():
                out[col] = values.round().astype("Int64")
    out.attrs["marks"] = [(tuple(key), (f"({col[0]})", col[1]), mark) for key, col, mark in marks]
    out.attrs["notes"] = notes
    return out


BEYOND_MARK = "†"
BEYOND_NOTE = "beyond the thesis's table: no thesis value to compare with"


def mark_beyond_thesis(table: pd.DataFrame, mark: str = BEYOND_MARK, note: str = BEYOND_NOTE) -> list:
    """Mark our values in the rows of a :func:`multibody_table`-like table without any thesis value.

    A row counts as beyond the thesis's table when the table has ``*_thesis``
    columns and all of them are missing in that row; our value cells (not
    ``*_thesis`` / ``*_dev``) of such rows get ``mark`` (appended to a mark
    already there), and ``note`` is added to ``table.attrs["notes"]``. Changes
    ``table.attrs`` in place.

    Returns
    -------
    list
        The index keys of the marked rows (empty without thesis columns).
    """
    thesis_cols = [c for c in table.columns if str(c[-1] if isinstance(c, tuple) else c).endswith("_thesis")]
    if not thesis_cols:
        return []
    ours = [c for c in table.columns
            if not str(c[-1] if isinstance(c, tuple) else c).endswith(("_thesis", "_dev"))]
    beyond = table[thesis_cols].isna().all(axis=1)
    keys = [key for key, flag in zip(table.index, beyond) if flag]
    marks = {(key, col): m for key, col, m in table.attrs.get("marks", [])}
    for key in keys:
        for col in ours:
            if not _is_missing(table.at[key, col]):
                marks[(key, col)] = marks.get((key, col), "") + mark
    table.attrs["marks"] = [(key, col, m) for (key, col), m in marks.items()]
    if keys:
        table.attrs["notes"] = {**table.attrs.get("notes", {}), mark: note}
    return keys


def hbhs_sweep_table(df: pd.DataFrame, theses: Mapping[str, pd.DataFrame | None], *,
                     base: Sequence[int], contacts: Sequence[str] = ("full", "middle"),
                     quantities: Mapping[str, Sequence[str]] | None = None,
                     rule_set: str = DEFAULT) -> pd.DataFrame:
    """Both methods along the H_b/H_s sweep from ``base``, our values beside the thesis's.

    Only the runs of rule set ``rule_set`` (:func:`~ddstudies.report.rule_sets.one_rule_set`).

    Parameters
    ----------
    df : DataFrame
        Aggregated runs (see :func:`multibody_table`).
    theses : mapping
        ``{method: thesis transcription or None}``, e.g. ``{"feti-feti": table 4.1,
        "hybrid": table 4.2}``; the methods shown, in this order.
    base : (bodies, subdomains, elements)
        1/H_b and H_s/h are fixed at ``base``; all our H_b/H_s values are rows.
    quantities : mapping, optional
        ``{method: quantities}``; default cond and iterations for FETI-FETI,
        iterations otherwise.

    Returns
    -------
    DataFrame
        Index H_b/H_s; columns ``("(I) FETI-FETI", "cond")``, ``(..., "cond_thesis")``,
        ``("(I) hybrid", "iterations")``, ... (no dev. columns). Rows beyond the
        thesis's tables are marked by :func:`mark_beyond_thesis`; not converged
        counts as in :func:`condition_table`.
    """
    quantities = dict(quantities or {})
    shown_set = chosen_rule_set(df, rule_set)
    df = one_rule_set(df, rule_set)   # one run per case (a study may sweep `presets`)
    data = df[(pd.to_numeric(df["bodies"]) == int(base[0])) & (pd.to_numeric(df["elements"]) == int(base[2]))]
    parts, marks = [], []
    for method, thesis in theses.items():
        qs = list(quantities.get(method, ["cond", "iterations"] if method == "feti-feti" else ["iterations"]))
        if data[data["method"] == method].empty:
            continue
        table = multibody_table(data, thesis, method=method, quantities=qs, contacts=contacts)
        label = METHOD_LABELS.get(method, method)
        marks += [(key[1], (f"{col[0]} {label}", col[1]), mark) for key, col, mark in table.attrs["marks"]]
        table = table[[c for c in table.columns if not c[1].endswith("_dev")]]
        table.columns = pd.MultiIndex.from_tuples([(f"{case} {label}", q) for case, q in table.columns],
                                                  names=["case", "quantity"])
        table.index = pd.Index(table.index.get_level_values("H_b/H_s"), name="H_b/H_s")
        parts.append(table)
    if not parts:
        return pd.DataFrame()
    out = pd.concat(parts, axis=1)
    out = out[[c for case in contacts for c in out.columns
               if c[0].startswith(f"({CONTACT_CASES[case]}) ")]].sort_index()
    out.attrs = {"marks": marks, "notes": {NOT_CONVERGED_MARK: NOT_CONVERGED_NOTE} if marks else {}}
    if shown_set != DEFAULT:
        out.attrs["notes"]["Rule sets:"] = only_sentence(shown_set)
    mark_beyond_thesis(out)
    return out


def growth_table(growth: pd.DataFrame) -> pd.DataFrame:
    """Display frame of :func:`ddstudies.report.plots.hbhs_growth` (render with :func:`to_markdown`).

    Columns: case, method, quantity, the two H_b/H_s values compared with the
    values there and their ratio, the fitted law and its a, b, R^2 (least
    squares over the whole sweep; "2 points (exact)" where two points determine the law), and on the
    hybrid rows the H_b/H_s where the fitted FETI-FETI iterations reach the fitted hybrid iterations.
    """
    rows = []
    for _, r in growth.iterrows():
        cond = r["quantity"] == "cond"
        value = (lambda v: "-" if _is_missing(v) else (f"{v:.2f}" if cond else f"{v:.0f}"))
        rows.append({
            "case": r["case"], "method": METHOD_LABELS.get(r["method"], r["method"]),
            "quantity": QUANTITY_LABELS.get(r["quantity"], r["quantity"]),
            "H_b/H_s": f"{int(r['from'])} → {int(r['to'])}",
            "values": f"{value(r['at_from'])} → {value(r['at_to'])}",
            "ratio": "-" if _is_missing(r["ratio"]) else f"×{r['ratio']:.2f}",
            "fitted law": r["law"],
            "a": "-" if _is_missing(r["a"]) else f"{r['a']:.3g}",
            "b": "-" if _is_missing(r["b"]) else f"{r['b']:.3g}",
            # two points fit a two-parameter law exactly: R^2 = 1 says nothing (as the figures' legends)
            "R²": "-" if _is_missing(r["r2"]) else r2_text(r["r2"], int(r.get("points", 3))),
            "fits cross at H_b/H_s": "-" if _is_missing(r["crossing"]) else f"{r['crossing']:.0f}",
        })
    return pd.DataFrame(rows, columns=["case", "method", "quantity", "H_b/H_s", "values", "ratio",
                                       "fitted law", "a", "b", "R²", "fits cross at H_b/H_s"])


def describe_constants(df: pd.DataFrame, params: Iterable[str] = DESCRIBED_PARAMS) -> str:
    """One line ``name=value, ...`` of the parameters that are the same for all runs."""
    parts = []
    for name in params:
        if name in df.columns:
            values = df[name].dropna().unique()
            if len(values) == 1:
                parts.append(f"{name}={_plain(values[0])}")
    return ", ".join(parts)


def _plain(value: Any) -> str:
    if isinstance(value, (float, np.floating)) and float(value).is_integer():
        return str(int(value))
    if isinstance(value, (np.generic,)):
        return str(value.item())
    return str(value)


# ----------------------------------------------------------------------------
# rendering
# ----------------------------------------------------------------------------

def _is_missing(value: Any) -> bool:
    if value is None or value is pd.NA:
        return True
    try:
        return bool(isinstance(value, (float, np.floating)) and math.isnan(value))
    except TypeError:
        return False


#: Quantities shown in scientific notation: residuals that span decades.
SCIENTIFIC_QUANTITIES: frozenset[str] = frozenset({"KKT stationarity", "kkt_stationarity", "kkt_residual"})


def _column_kind(name: Any, series: pd.Series) -> str:
    """'dev' (relative deviation), 'int', 'float', 'sci' or 'other' for formatting."""
    parts = [str(part) for part in (name if isinstance(name, tuple) else (name,))]
    last = parts[-1]
    if last.endswith("_dev") or last == "dev":
        return "dev"
    if pd.api.types.is_bool_dtype(series.dtype):
        return "other"
    if pd.api.types.is_integer_dtype(series.dtype):
        return "int"
    if pd.api.types.is_float_dtype(series.dtype) and SCIENTIFIC_QUANTITIES.intersection(parts):
        return "sci"
    if pd.api.types.is_float_dtype(series.dtype):
        values = series.dropna()
        quantity = last.removesuffix("_thesis")
        integral = len(values) > 0 and values.map(lambda v: float(v).is_integer()).all()
        if integral and (quantity in INTEGER_QUANTITIES or quantity.startswith("iter")
                         or quantity.endswith("_it") or quantity.endswith("iterations")):
            return "int"
        return "float"
    return "other"


def _format(value: Any, kind: str, digits: int, missing: str) -> str:
    if _is_missing(value):
        return missing
    if kind == "dev":
        return f"{float(value):+.1%}"
    if kind == "int":
        return str(int(round(float(value))))
    if kind == "float":
        return f"{float(value):.{digits}f}"
    if kind == "sci":
        return f"{float(value):.1e}"
    return str(value)


def _layout(table: pd.DataFrame, digits: int, missing: str):
    """Common part of the renderers: (groups, labels, cell rows, notes)."""
    marks = {(key, col): mark for key, col, mark in table.attrs.get("marks", [])}
    notes = dict(table.attrs.get("notes", {}))
    multi = isinstance(table.columns, pd.MultiIndex)
    index_names = [n for n in table.index.names if n is not None]
    groups: list[str] = [""] * len(index_names)
    labels: list[str] = [ROW_LABELS.get(n, str(n)) for n in index_names]
    for col in table.columns:
        if multi:
            groups.append(METHOD_LABELS.get(str(col[0]), str(col[0])))
            labels.append(QUANTITY_LABELS.get(str(col[-1]), str(col[-1])))
        else:
            groups.append("")
            labels.append(ROW_LABELS.get(str(col), str(col)))
    kinds = [_column_kind(col, table[col]) for col in table.columns]
    index_kinds = []
    for level, name in enumerate(index_names):
        values = pd.Series(table.index.get_level_values(level))
        index_kinds.append(_column_kind(name, values))
    cells = []
    for i, key in enumerate(table.index):
        key_tuple = key if isinstance(key, tuple) else (key,)
        row = [_format(v, k, digits, missing) for v, k in zip(key_tuple, index_kinds)] if index_names else []
        for j, col in enumerate(table.columns):
            text = _format(table.iat[i, j], kinds[j], digits, missing)
            mark = marks.get((key, col))
            row.append(text + mark if mark and text != missing else text)
        cells.append(row)
    return groups, labels, cells, notes


def to_markdown(table: pd.DataFrame, *, digits: int = 4, missing: str = "-") -> str:
    """Render a table (wide or flat) as a GitHub Markdown table.

    Column headers of a wide table read ``<METHOD> <quantity>`` (e.g.
    ``FETI-DP cond``); floats get ``digits`` decimals, relative deviations are
    percentages, missing values are ``missing``. Footnotes for marked cells
    follow the table.
    """
    groups, labels, cells, notes = _layout(table, digits, missing)
    headers = [f"{g} {l}".strip() for g, l in zip(groups, labels)]
    if not cells:
        cells = [[missing] * len(headers)]
    frame = pd.DataFrame(cells, columns=range(len(headers)))
    frame.columns = headers
    text = frame.to_markdown(index=False, disable_numparse=True, stralign="right")
    for mark, note in notes.items():
        text += f"\n\n{mark} {note}"
    return text + "\n"


_LATEX_ESCAPES = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\^{}",
                  "†": r"\textdagger{}", "‡": r"\textdaggerdbl{}", "|": r"\textbar{}",   # OT1 has no | nor †
                  # pdflatex's utf8 input has no glyph for these (the growth table used them; a review)
                  "→": r"$\to$", "√": r"$\surd$", "²": r"\textsuperscript{2}", "³": r"\textsuperscript{3}",
                  "×": r"$\times$", "·": r"$\cdot$", "≤": r"$\le$", "≥": r"$\ge$", "≈": r"$\approx$",
                  "ρ": r"$\rho$", "λ": r"$\lambda$", "κ": r"$\kappa$", "ε": r"$\varepsilon$", "Γ": r"$\Gamma$",
                  "‖": r"$\|$", "∞": r"$\infty$", "₊": r"$_+$", "⁺": r"$^+$", "⁻": r"$^-$", "°": r"$^\circ$",
                  "−": "-", "–": "--"}


def latex_escape(text: str) -> str:
    """Escape LaTeX special characters in plain text."""
    return "".join(_LATEX_ESCAPES.get(ch, ch) for ch in str(text))


def _latex_label(label: str) -> str:
    return LATEX_LABELS.get(label, latex_escape(label))


def to_latex(table: pd.DataFrame, *, digits: int = 4, missing: str = "--") -> str:
    """Render a table (wide or flat) as a booktabs ``tabular`` (needs ``\\usepackage{booktabs}``).

    A wide table gets a first header row with one ``\\multicolumn`` per method
    and ``\\cmidrule`` under each; footnotes for marked cells follow
    ``\\bottomrule`` in a spanning row.
    """
    groups, labels, cells, notes = _layout(table, digits, missing)
    ncol = len(labels)
    lines = ["% generated by ddstudies.report.tables.to_latex; needs \\usepackage{booktabs}",
             "\\begin{tabular}{" + "r" * ncol + "}", "\\toprule"]
    if any(groups):
        spans: list[tuple[str, int, int]] = []  # (label, first, last) 1-based
        for j, g in enumerate(groups, start=1):
            if spans and spans[-1][0] == g and g:
                spans[-1] = (g, spans[-1][1], j)
            else:
                spans.append((g, j, j))
        head, rules = [], []
        for g, a, b in spans:
            if not g:
                head.extend([""] * (b - a + 1))
                continue
            head.append(f"\\multicolumn{{{b - a + 1}}}{{c}}{{{latex_escape(g)}}}")
            rules.append(f"\\cmidrule(lr){{{a}-{b}}}")
        lines.append(" & ".join(head) + " \\\\")
        lines.append(" ".join(rules))
    lines.append(" & ".join(_latex_label(l) for l in labels) + " \\\\")
    lines.append("\\midrule")
    for row in cells:
        lines.append(" & ".join(latex_escape(c) for c in row) + " \\\\")
    lines.append("\\bottomrule")
    for mark, note in notes.items():
        lines.append(f"\\multicolumn{{{ncol}}}{{l}}{{\\footnotesize {latex_escape(mark)} "
                     f"{latex_escape(note)}}} \\\\")
    lines.append("\\end{tabular}")
    return "\n".join(lines) + "\n"
