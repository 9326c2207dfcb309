"""Tables of the contact study (problem (3.1)): Tables 5.1 and 6.1 of the thesis, side by side.

:func:`contact_table` puts one method's runs in the layout of Table 5.1 (active
set method + hybrid method) or Table 6.1 (SMALBE): rows (N_sub(1/H), H/h) with
N_sub = N^2 subdomains per membrane and 1/H = N, one column group per quantity
(:data:`CONTACT_TABLES`) holding our value, the thesis's and the relative
deviation (ours - thesis) / |thesis|. For the list of inner iterations per outer
iteration only the two lists are shown.

:func:`method_comparison` lists, per grid, the total iterations and wall times
of both methods (with the thesis's totals), and :func:`comparison_caption`
states, computed from it, whether the active set method needs fewer total
iterations than SMALBE on the larger grids.

Render the tables with :func:`ddstudies.report.tables.to_markdown` or
:func:`contact_latex` (booktabs, math-mode labels).
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from ..aggregate import parse_list
from .rule_sets import DEFAULT, RULE_SET_COLUMN, by_rule_set, chosen_rule_set, one_rule_set, rule_sets
from .tables import NOT_CONVERGED_MARK, NOT_CONVERGED_NOTE, describe_constants, to_latex, to_markdown

#: Our key columns -> the key columns of the thesis transcriptions (table_5_1.csv, table_6_1.csv).
THESIS_KEYS: dict[str, str] = {"subdomains": "inv_H", "elements": "H_over_h"}
#: Display names of the row keys (the thesis's notation).
ROW_NAMES: tuple[str, str] = ("N_sub(1/H)", "H/h")

#: Columns of the thesis's tables: (our column, thesis column, display label, kind);
#: kind "int" gets thesis and deviation columns, "list" only the thesis's list.
TABLE_5_1_COLUMNS: tuple[tuple[str, str, str, str], ...] = (
    ("nlambda", "ndof_lambda", "N_dof(λ)", "int"),
    ("ndof", "ndof_total", "N_dof(total)", "int"),
    ("pcg_iterations", "pcg_it", "PCG it.", "int"),
    ("outer_iterations", "outer_it", "outer it.", "int"),
    ("inner_iterations", "inner_it", "inner it.", "list"),
    ("total_iterations", "total_it", "total it.", "int"),
)
TABLE_6_1_COLUMNS: tuple[tuple[str, str, str, str], ...] = tuple(
    c for c in TABLE_5_1_COLUMNS if c[0] != "pcg_iterations")

#: The two thesis tables: the method they show, their columns and a title.
CONTACT_TABLES: dict[str, dict[str, Any]] = {
    "table_5_1": {
        "method": "active-set", "columns": TABLE_5_1_COLUMNS,
        "title": "Table 5.1: active set method + hybrid method",
        "legend": ("N_dof(λ): contact multipliers, one per node pair on Γ_c; N_dof(total): free "
                   "primal dofs of both membranes; PCG it.: PCG iterations on (5.4) for the initial "
                   "active set; outer it.: outer iterations of the active set method (Figure 6.3); "
                   "inner it.: PCR iterations of the hybrid face solve of each outer iteration; "
                   "total it.: their sum")},
    "table_6_1": {
        "method": "smalbe", "columns": TABLE_6_1_COLUMNS,
        "title": "Table 6.1: SMALBE (MPRGP inner solver) on the FETI-DP dual (6.17)",
        "legend": ("N_dof(λ): FETI-DP multipliers, inside each membrane and on Γ_c; N_dof(total): "
                   "free primal dofs of both membranes; outer it.: SMALBE iterations (Figure 6.7); "
                   "inner it.: MPRGP iterations of each outer iteration (Figure 6.6); total it.: "
                   "their sum")},
}
#: A run whose own stopping rule was met but whose result ddsolve's checks refused (reason "not accepted").
REJECTED_MARK = "‡"
REJECTED_NOTE = ("stopping rule met, but the result was rejected by ddsolve's checks (the force balance of the "
                 "floating membrane, the KKT residual, or, for SMALBE, an active set that is not the solution's; "
                 "the run's reason says which): not converged, and not comparable with the thesis's count; the "
                 "count is where it stopped")

CONTACT_METHOD_LABELS: dict[str, str] = {"active-set": "active set", "smalbe": "SMALBE", "direct": "direct"}

#: Labels typeset in math mode by :func:`contact_latex` (after escaping by to_latex).
LATEX_REPLACEMENTS: dict[str, str] = {
    r"N\_sub(1/H)": r"$N_{sub}(1/H)$",
    r"N\_dof($\lambda$)": r"$N_{dof}(\lambda)$",
    r"N\_dof(total)": r"$N_{dof}(total)$",
}


def _row_key(subdomains: int, elements: int) -> tuple[str, int]:
    """Display key of a grid: ``("16(4)", 8)`` for N = 4, H/h = 8."""
    n = int(subdomains)
    return f"{n * n}({n})", int(elements)


def _list_text(cell: Any) -> str | float:
    values = parse_list(cell)
    return " ".join(str(v) for v in values) if values else math.nan


def _truthy(value: Any) -> bool:
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    return str(value).strip().lower() in ("true", "1", "yes")


def _grid_frame(df: pd.DataFrame, method: str) -> pd.DataFrame:
    """The runs of ``method``, keys as int, sorted by (N, H/h); one row per grid."""
    missing = [c for c in ("method", *THESIS_KEYS) if c not in df.columns]
    if missing:
        raise KeyError(f"contact tables: missing column(s) {', '.join(missing)}")
    data = df[df["method"] == method].copy()
    for key in THESIS_KEYS:
        data[key] = pd.to_numeric(data[key]).astype("int64")
    if data.duplicated(subset=list(THESIS_KEYS)).any():
        raise ValueError(f"contact tables: several {method} runs for the same (N, H/h)")
    return data.sort_values(list(THESIS_KEYS), kind="stable").reset_index(drop=True)


def contact_table(df: pd.DataFrame, thesis: pd.DataFrame | None = None, *,
                  method: str = "active-set",
                  columns: Sequence[tuple[str, str, str, str]] = TABLE_5_1_COLUMNS) -> pd.DataFrame:
    """One method's contact runs in the layout of Table 5.1 / 6.1, beside the thesis.

    Parameters
    ----------
    df : DataFrame
        Aggregated runs (summary CSV or :func:`ddstudies.aggregate.collect`), with
        ``method``, ``subdomains``, ``elements``, the ``columns``' our names and
        optionally ``converged``. List cells may be lists or space-separated strings.
    thesis : DataFrame, optional
        The transcription (``config/thesis_tables/table_5_1.csv`` / ``table_6_1.csv``)
        with the keys of :data:`THESIS_KEYS`. Without it only our values are shown.
    method : str
        The method shown.
    columns : sequence of (ours, thesis, label, kind)
        :data:`TABLE_5_1_COLUMNS` or :data:`TABLE_6_1_COLUMNS`.

    Returns
    -------
    DataFrame
        Index (N_sub(1/H), H/h), our grids sorted by (N, H/h); columns a
        MultiIndex ``(label, "ours" | "thesis" | "dev")``; integer columns as
        Int64, deviations as floats, lists as space-separated strings. A run
        that did not converge has its total marked ``*`` (``attrs["marks"]``,
        ``attrs["notes"]``, as in :func:`ddstudies.report.tables.condition_table`).
        With a column ``preset`` in ``df`` (several rule sets), the rows are
        paired per rule set (:func:`ddstudies.report.rule_sets.by_rule_set`).

    Raises
    ------
    KeyError
        If a needed column is missing.
    ValueError
        If a grid has two runs of ``method``.
    """
    if RULE_SET_COLUMN in df.columns:    # several rule sets (the spec's preset): paired rows
        return by_rule_set(df, lambda runs: contact_table(runs, thesis, method=method, columns=columns))
    data = _grid_frame(df, method)
    missing = [c[0] for c in columns if c[0] not in data.columns]
    if missing:
        raise KeyError(f"contact_table: missing column(s) {', '.join(missing)}")
    ref = None
    if thesis is not None:
        ref = thesis.rename(columns={v: k for k, v in THESIS_KEYS.items()})
        ref = ref.astype({k: "int64" for k in THESIS_KEYS})
        if ref.duplicated(subset=list(THESIS_KEYS)).any():
            raise ValueError("contact_table: the thesis table lists a grid more than once")
        ref = data[list(THESIS_KEYS)].merge(ref, on=list(THESIS_KEYS), how="left")
    out: dict[tuple[str, str], pd.Series] = {}
    for ours, theirs, label, kind in columns:
        have_ref = ref is not None and theirs in ref.columns
        if kind == "list":
            out[(label, "ours")] = data[ours].map(_list_text)
            if have_ref:
                out[(label, "thesis")] = ref[theirs].map(_list_text)
            continue
        mine = pd.to_numeric(data[ours], errors="coerce")
        out[(label, "ours")] = mine.round().astype("Int64")
        if have_ref:
            printed = pd.to_numeric(ref[theirs], errors="coerce")
            out[(label, "thesis")] = printed.round().astype("Int64")
            dev = (mine.astype(float) - printed.astype(float)) / printed.astype(float).abs()
            out[(label, "dev")] = dev.where(printed != 0)
    table = pd.DataFrame(out)
    table.columns = pd.MultiIndex.from_tuples(list(out), names=["quantity", "source"])
    table.index = pd.MultiIndex.from_tuples(
        [_row_key(s, m) for s, m in zip(data["subdomains"], data["elements"])], names=list(ROW_NAMES))
    marks = []
    total = next((c[2] for c in columns if c[0] == "total_iterations"), None)
    if "converged" in data.columns and total is not None:
        reasons = data["reason"].astype(str) if "reason" in data.columns else pd.Series([""] * len(data))
        for key, ok, why in zip(table.index, data["converged"], reasons):
            if not _truthy(ok):
                rejected = why.startswith("not accepted")
                marks.append((key, (total, "ours"), REJECTED_MARK if rejected else NOT_CONVERGED_MARK))
    table.attrs["marks"] = marks
    kinds = {mark for _, _, mark in marks}
    table.attrs["notes"] = {**({NOT_CONVERGED_MARK: NOT_CONVERGED_NOTE} if NOT_CONVERGED_MARK in kinds else {}),
                            **({REJECTED_MARK: REJECTED_NOTE} if REJECTED_MARK in kinds else {})}
    return table


def wall_seconds(df: pd.DataFrame) -> pd.Series:
    """Wall time of each run: ``setup_seconds + solve_seconds`` (assembly, factorizations, iterations)."""
    return pd.to_numeric(df["setup_seconds"], errors="coerce") + pd.to_numeric(df["solve_seconds"],
                                                                               errors="coerce")


def method_comparison(df: pd.DataFrame, theses: Mapping[str, pd.DataFrame | None] | None = None, *,
                      methods: Sequence[str] = ("active-set", "smalbe")) -> pd.DataFrame:
    """Total iterations and wall time per grid, one column per method, with the thesis's totals.

    Parameters
    ----------
    df : DataFrame
        Aggregated runs with ``method``, ``subdomains``, ``elements``, ``ndof``,
        ``total_iterations``, ``setup_seconds``, ``solve_seconds``.
    theses : mapping, optional
        ``{method: transcription}`` (``total_it`` column), e.g. ``{"active-set":
        table 5.1, "smalbe": table 6.1}``.
    methods : sequence of str
        The methods compared, in column order.

    Returns
    -------
    DataFrame
        Index (N_sub(1/H), H/h) over the grids of any method, sorted by (N, H/h);
        columns ``("N_dof(total)", "")``, ``("total it.", <method label>)``,
        ``("total it.", <method label> + " printed")`` (the thesis's table, where a transcription is
        given) and ``("wall time [s]", <method label>)``. ``attrs["grids"]``
        holds the (N, H/h) pairs of the rows.
    """
    theses = dict(theses or {})
    frames = {m: _grid_frame(df, m) for m in methods}
    grids = sorted({(int(s), int(e)) for f in frames.values() for s, e in zip(f["subdomains"], f["elements"])})
    index = pd.MultiIndex.from_tuples([_row_key(*g) for g in grids], names=list(ROW_NAMES))
    out = pd.DataFrame(index=index)
    ndof = pd.Series(np.nan, index=range(len(grids)))
    for frame in frames.values():
        pos = {g: i for i, g in enumerate(grids)}
        for s, e, n in zip(frame["subdomains"], frame["elements"], pd.to_numeric(frame["ndof"])):
            ndof[pos[(int(s), int(e))]] = n
    out[("N_dof(total)", "")] = ndof.round().astype("Int64").to_numpy()

    def lookup(frame: pd.DataFrame, column: str) -> np.ndarray:
        values = {(int(s), int(e)): v for s, e, v in zip(frame["subdomains"], frame["elements"], frame[column])}
        return pd.to_numeric(pd.Series([values.get(g, np.nan) for g in grids]), errors="coerce").to_numpy()

    for m in methods:
        label = CONTACT_METHOD_LABELS.get(m, m)
        out[("total it.", label)] = pd.array(np.round(lookup(frames[m], "total_iterations")), dtype="Int64")
        if theses.get(m) is not None:
            ref = theses[m].rename(columns={v: k for k, v in THESIS_KEYS.items()})
            ref = ref.assign(subdomains=ref["subdomains"].astype("int64"), elements=ref["elements"].astype("int64"))
            out[("total it.", f"{label} printed")] = pd.array(np.round(lookup(ref, "total_it")), dtype="Int64")
    for m in methods:
        label = CONTACT_METHOD_LABELS.get(m, m)
        frame = frames[m].assign(wall_seconds=wall_seconds(frames[m]))
        out[("wall time [s]", label)] = lookup(frame, "wall_seconds")
    for m in methods:
        if "kkt_stationarity" in frames[m]:
            label = CONTACT_METHOD_LABELS.get(m, m)
            polished = "polish" in frames[m] and frames[m]["polish"].astype(str).isin(["accepted", "rescued"]).any()
            out[("KKT stationarity", f"{label} + polish" if polished else label)] = lookup(frames[m], "kkt_stationarity")
    for m in methods:        # SMALBE's polish: its PCG iterations are not in "total it." (Table 6.1's count)
        if "polish_iterations" in frames[m] and pd.to_numeric(frames[m]["polish_iterations"],
                                                               errors="coerce").notna().any():
            polish = pd.to_numeric(pd.Series(lookup(frames[m], "polish_iterations")), errors="coerce")
            out[("polish PCG it.", CONTACT_METHOD_LABELS.get(m, m))] = pd.array(np.round(polish), dtype="Int64")
    out.columns = pd.MultiIndex.from_tuples(out.columns, names=["quantity", "source"])
    out.attrs["grids"] = grids
    # runs that did not converge (or were rejected) are marked, and the caption leaves their grids out
    marks, converged = [], {}
    for m in methods:
        label = CONTACT_METHOD_LABELS.get(m, m)
        frame = frames[m]
        ok = {(int(s), int(e)): _truthy(c) for s, e, c in zip(frame["subdomains"], frame["elements"],
                                                               frame.get("converged", pd.Series(True, index=frame.index)))}
        why = {(int(s), int(e)): str(r) for s, e, r in zip(frame["subdomains"], frame["elements"],
                                                           frame.get("reason", pd.Series("", index=frame.index)))}
        converged[label] = np.array([ok.get(g, True) for g in grids], dtype=bool)
        for g, key in zip(grids, index):
            if g in ok and not ok[g]:
                marks.append((key, ("total it.", label),
                              REJECTED_MARK if why[g].startswith("not accepted") else NOT_CONVERGED_MARK))
    kinds = {mark for _, _, mark in marks}
    out.attrs["marks"] = marks
    out.attrs["notes"] = {**({NOT_CONVERGED_MARK: NOT_CONVERGED_NOTE} if NOT_CONVERGED_MARK in kinds else {}),
                          **({REJECTED_MARK: REJECTED_NOTE} if REJECTED_MARK in kinds else {})}
    out.attrs["converged"] = converged
    return out


def larger_grids(comparison: pd.DataFrame) -> np.ndarray:
    """Mask of the larger grids: N_dof(total) at least the median over the grids."""
    ndof = pd.to_numeric(comparison[("N_dof(total)", "")], errors="coerce").astype(float).to_numpy()
    return ndof >= np.nanmedian(ndof)


def _fewer(comparison: pd.DataFrame, mask: np.ndarray, a: str, b: str) -> tuple[float, float, int, int] | None:
    """(sum a, sum b, grids where a < b, grids compared) over ``mask`` where both are known."""
    if ("total it.", a) not in comparison.columns or ("total it.", b) not in comparison.columns:
        return None
    x = pd.to_numeric(comparison[("total it.", a)], errors="coerce").astype(float).to_numpy()
    y = pd.to_numeric(comparison[("total it.", b)], errors="coerce").astype(float).to_numpy()
    both = mask & np.isfinite(x) & np.isfinite(y)
    if not both.any():
        return None
    return float(x[both].sum()), float(y[both].sum()), int(np.sum(x[both] < y[both])), int(both.sum())


def comparison_caption(comparison: pd.DataFrame, *, methods: Sequence[str] = ("active-set", "smalbe")) -> str:
    """One line: does the first method need fewer total iterations than the second on the larger grids?

    The larger grids are those of :func:`larger_grids`. The answer is "yes" when
    the first method's total iterations summed over those grids are smaller,
    and it is given for our runs and, where the comparison has them, for the
    thesis's numbers, with the number of grids on which the first is smaller.
    """
    a, b = (CONTACT_METHOD_LABELS.get(m, m) for m in methods[:2])
    mask = larger_grids(comparison)
    ndof = pd.to_numeric(comparison[("N_dof(total)", "")], errors="coerce").astype(float)
    threshold = int(np.nanmedian(ndof.to_numpy()))
    parts = []
    converged = comparison.attrs.get("converged", {})
    both = np.ones(len(mask), dtype=bool)
    for label in (a, b):
        both &= converged.get(label, np.ones(len(mask), dtype=bool))
    left_out = int(np.sum(mask & ~both))
    for who, (ca, cb) in (("ours", (a, b)), ("printed in the thesis", (f"{a} printed", f"{b} printed"))):
        ours = who == "ours"
        res = _fewer(comparison, mask & both if ours else mask, ca, cb)
        if res is None:
            if ours and left_out:
                parts.append(f"ours: not compared ({left_out} grid(s) left out: a run did not converge)")
            continue
        sa, sb, k, n = res
        out_note = (f"; {left_out} grid(s) left out: a run did not converge or was rejected"
                    if ours and left_out else "")
        parts.append(f"{who}: {'yes' if sa < sb else 'no'} ({sa:.0f} vs {sb:.0f} summed; "
                     f"fewer on {k} of {n} grids{out_note})")
    verdict = "; ".join(parts) if parts else "no grid has both methods"
    return (f"Does the {a} method need fewer total iterations than {b} on the larger grids "
            f"(N_dof(total) >= {threshold}, {int(mask.sum())} of {len(mask)} grids)? {verdict}.")


def contact_latex(table: pd.DataFrame, **kwargs: Any) -> str:
    """:func:`ddstudies.report.tables.to_latex` with the thesis's labels in math mode."""
    text = to_latex(table, **kwargs)
    for plain, math_label in LATEX_REPLACEMENTS.items():
        text = text.replace(plain, math_label)
    return text


def _legend_tail(runs: pd.DataFrame) -> str:
    constants = describe_constants(runs)
    return (" N_sub(1/H): N_sub = N^2 subdomains per membrane, 1/H = N; H/h: Q1 elements per "
            "subdomain side; thesis: the value printed in the thesis; dev. = (ours − thesis)/|thesis|."
            + (f" {constants}." if constants else ""))


def render_contact_table(df: pd.DataFrame, thesis: pd.DataFrame | None, name: str) -> tuple[str, str]:
    """Markdown page and LaTeX ``tabular`` of one thesis table (:data:`CONTACT_TABLES` key).

    Parameters
    ----------
    df : DataFrame
        Aggregated runs (the study's summary CSV).
    thesis : DataFrame or None
        The transcription of the table.
    name : str
        ``"table_5_1"`` or ``"table_6_1"``.

    Returns
    -------
    (str, str)
        Markdown (heading, legend, table) and LaTeX (:func:`contact_latex`).
    """
    entry = CONTACT_TABLES[name]
    table = contact_table(df, thesis, method=entry["method"], columns=entry["columns"])
    runs = df[df["method"] == entry["method"]]
    heading = f"# {entry['title']}\n\n{entry['legend']}.{_legend_tail(runs)}\n\n"
    return heading + to_markdown(table), contact_latex(table)


def render_comparison(df: pd.DataFrame, theses: Mapping[str, pd.DataFrame | None],
                      methods: Sequence[str] = ("active-set", "smalbe"),
                      rule_set: str = DEFAULT) -> tuple[str, str, pd.DataFrame, str]:
    """The method comparison as Markdown and LaTeX, with its computed caption.

    Only the runs of rule set ``rule_set`` (:func:`~ddstudies.report.rule_sets.one_rule_set`);
    the page names it when the study ran several.

    Returns
    -------
    (str, str, DataFrame, str)
        Markdown page, LaTeX ``tabular``, the :func:`method_comparison` frame and
        the :func:`comparison_caption` line.
    """
    ran = rule_sets(df)
    rule_set = chosen_rule_set(df, rule_set)
    df = one_rule_set(df, rule_set)   # one run per grid and method (a study may sweep `presets`)
    table = method_comparison(df, theses, methods=methods)
    caption = comparison_caption(table, methods=methods)
    others = [name for name in ran if name != rule_set]
    shown = (f"Rule set: {rule_set} (the runs of the other rule sets of the study, {', '.join(others)}, are in "
             "Tables 5.1 / 6.1).\n\n" if others else
             f"Rule set: {rule_set}, the only one this study ran.\n\n" if rule_set != DEFAULT else "")
    heading = ("# Active set + hybrid vs SMALBE: total iterations and wall time per grid\n\n"
               f"{shown}{caption}\n\n"
               "total it.: the sum of the inner iterations (Tables 5.1 / 6.1; the active set method's "
               "PCG iterations for the initial guess are not included, as in the thesis); printed: the "
               "thesis's Table 5.1 / 6.1; polish PCG it.: the iterations of SMALBE's polish (ddsolve's "
               "default rules: a FETI-FETI PCG solve on SMALBE's active set, not in total it.), whose "
               "solution replaces SMALBE's where it is accepted, so that the KKT column of \"SMALBE + "
               "polish\" is the polish's accuracy, not SMALBE's own; wall time: setup_seconds + solve_seconds of the run (assembly, "
               "factorizations and iterations; one BLAS thread, on a shared machine); KKT stationarity: "
               "||Ku - f + B^T lambda|| / (||f|| + ||B^T lambda||) of the returned solution. The two "
               "methods stop on different quantities (the active set method's face solves reduce the "
               "residual of (4.5) by 1e-5; SMALBE's epsilon = 1e-5 bounds its projected gradient "
               "relative to ||b|| of the dual problem and the floating body's force imbalance), so "
               "compare the iterations together with the KKT columns.\n\n")
    return heading + to_markdown(table, digits=2), contact_latex(table, digits=2), table, caption
