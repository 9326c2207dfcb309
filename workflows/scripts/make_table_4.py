"""Snakemake script of rule table_4: summary CSV + thesis transcriptions -> <table>.md and .tex.

Inputs from Snakemake: input.summary, input.thesis (one path or a list), output.md,
output.tex, params.table (TABLES_4 entry: method, quantities, title; kind "growth"
for the H_b/H_s growth table beyond the thesis, with thesis = [table 4.1, table 4.2]),
params.contacts, params.cases (row order), params.base (the base case), log[0].
"""
from pathlib import Path

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.workflow import write_text
    from ddstudies.report.plots import hbhs_growth
    from ddstudies.report.rule_sets import chosen_rule_set, one_rule_set, rule_sets
    from ddstudies.report.tables import (describe_constants, growth_table,
                                       hbhs_sweep_table, mark_beyond_thesis, multibody_table, to_latex,
                                       to_markdown)

    sm = snakemake  # noqa: F821
    spec = sm.params.table
    df = pd.read_csv(sm.input.summary)
    thesis_paths = [sm.input.thesis] if isinstance(sm.input.thesis, str) else list(sm.input.thesis)
    theses = [pd.read_csv(path) for path in thesis_paths]
    names = ", ".join(Path(path).name for path in thesis_paths)
    # the hybrid method's stopping norm and projection as the runs used them (a review: a norm: M study's
    # table said ||.||_2)
    hybrid_runs = df[df["method"] == "hybrid"] if "method" in df.columns else df.iloc[0:0]

    def _used(column: str, default: str) -> str:
        values = sorted({str(v) for v in hybrid_runs[column].dropna()}) if column in hybrid_runs.columns else []
        return ", ".join(values) if values else default

    hybrid_norm = {"l2": "||.||_2", "M": "||.||_M"}.get(_used("norm", "l2"), _used("norm", "l2"))
    projection = _used("projection", "orthogonal")
    hybrid_projection = "" if projection == "orthogonal" else f", projection {projection}"
    legend = (
        "Problem (4.32): 1/H_b bodies per side, H_b/H_s subdomains per body side, H_s/h "
        "elements per subdomain side. Contact (I): continuity on the whole interface between "
        "bodies; (II): only on the middle third of each face between two bodies (cross points "
        "of bodies meeting at a corner inactive). "
        + ("cond: Lanczos estimate of the condition number; "
           if spec.get("cond", True) and "cond" in spec.get("quantities", ["cond"]) else "")
        + ("" if spec.get("cond", True) else "no condition estimates: the study sets cond: false; ")
        + "iter: Krylov iterations (stopping rule ||r_n||/||r_0|| < rtol: PCG for FETI-FETI, in ||.||_2 "
          "with the orthogonal projection under the thesis preset and on the Q-weighted residual of the "
          "projection P_Q under ddsolve's defaults, docs/methods.md; PCR for the hybrid method, in "
          f"{hybrid_norm}{hybrid_projection}); "
          f"thesis: the value printed in the thesis ({names})"
        + ("; rule set default: ddsolve's rules, thesis: the --preset thesis rules" if len(rule_sets(df)) > 1
           else ""))

    def constants(runs):
        text = describe_constants(runs)
        return f" {text}." if text else ""

    if spec.get("kind") == "growth":
        base = [int(v) for v in sm.params.base]
        several = len(rule_sets(df)) > 1
        shown_set = chosen_rule_set(df)     # the default's runs, or those of the one preset a study ran
        df = one_rule_set(df)   # one run per case: the default rule set's (the study may sweep `presets`)
        runs = df[df["method"].isin(["feti-feti", "hybrid"])]
        table = hbhs_sweep_table(df, dict(zip(["feti-feti", "hybrid"], theses)), base=base,
                                 contacts=sm.params.contacts,
                                 quantities=None if spec.get("cond", True) else {"feti-feti": ["iterations"]})
        growth = hbhs_growth(df, base=base, contacts=sm.params.contacts, start=int(spec.get("start", 4)))
        shown = growth_table(growth)
        beyond = [int(k) for k in table.index
                  if all(pd.isna(table.at[k, c]) for c in table.columns if c[1].endswith("_thesis"))]
        heading = (
            f"# {spec['title']} (study `{sm.wildcards.study}`)\n\n"
            f"H_b/H_s varies with 1/H_b = {base[0]} and H_s/h = {base[2]} fixed (H_b/h = "
            f"{base[2]} H_b/H_s). {legend}. Rows marked † ({', '.join(map(str, beyond)) or 'none'}) "
            f"go beyond the thesis's tables.{constants(runs)}"
            f"{' Runs of the default rule set only (the other presets: Tables 4.1 / 4.2).' if several else ''}"
            f"{f' Rule set {shown_set}, the only one this study ran.' if shown_set != 'default' else ''}\n\n")
        fits = (
            "\n## Growth in H_b/H_s\n\n"
            "values: ours at the two H_b/H_s values, ratio: their quotient; runs that did not converge "
            "(counts capped at maxiter, marked * above) are left out of these rows and of the fits. Fitted "
            "laws (least squares over the whole H_b/H_s sweep, natural log): FETI-FETI cond a + b H_b/H_s "
            "(linear, as Figure 4.2), FETI-FETI iterations a + b sqrt(H_b/H_s) (CG needs "
            "O(sqrt(cond)) steps), hybrid iterations a + b log(H_b/h) (the log(H_b/h) factor of "
            "Theorem 4.3.6 with H_s/h fixed). fits cross at: the H_b/H_s where the fitted "
            "FETI-FETI iterations reach the fitted hybrid iterations (a property of the two fits, "
            "extrapolated where it lies beyond the largest run; the measured counts need not have "
            "crossed there).\n\n")
        write_text(sm.output.md, heading + to_markdown(table) + fits + to_markdown(shown))
        write_text(sm.output.tex, to_latex(table) + "\n" + to_latex(shown))
        print(to_markdown(table) + fits + to_markdown(shown))
    else:
        table = multibody_table(df, theses[0], method=spec["method"], quantities=spec["quantities"],
                                contacts=sm.params.contacts, order=sm.params.cases)
        beyond = mark_beyond_thesis(table)
        rows = "; ".join("(" + ", ".join(str(v) for v in key) + ")" for key in beyond)
        extra = (f" Rows marked † ({rows}) go beyond the thesis's table (no thesis value)."
                 if beyond else "")
        runs = df[df["method"] == spec["method"]]
        heading = (
            f"# {spec['title']} (study `{sm.wildcards.study}`)\n\n"
            f"{legend}; dev.: (ours - thesis)/|thesis|.{extra}{constants(runs)}\n\n")
        write_text(sm.output.md, heading + to_markdown(table))
        write_text(sm.output.tex, to_latex(table))
        print(to_markdown(table))

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
