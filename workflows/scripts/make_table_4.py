"""Snakemake script of rule table_4: summary CSV + thesis transcription -> <table>.md and .tex.

Inputs from Snakemake: input.summary, input.thesis, output.md, output.tex,
params.table (TABLES_4 entry: method, quantities, title), params.contacts,
params.cases (row order), log[0].
"""
import sys
from pathlib import Path

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stdout = sys.stderr = log
    import pandas as pd

    from ddsolve.report.tables import describe_constants, multibody_table, to_latex, to_markdown

    sm = snakemake  # noqa: F821
    spec = sm.params.table
    df = pd.read_csv(sm.input.summary)
    thesis = pd.read_csv(sm.input.thesis)
    table = multibody_table(df, thesis, method=spec["method"], quantities=spec["quantities"],
                            contacts=sm.params.contacts, order=sm.params.cases)
    runs = df[df["method"] == spec["method"]]
    heading = (
        f"# {spec['title']} (study `{sm.wildcards.study}`)\n\n"
        "Problem (4.32): 1/H_b bodies per side, H_b/H_s subdomains per body side, H_s/h "
        "elements per subdomain side. Contact (I): continuity on the whole interface between "
        "bodies; (II): only on the middle third of each face between two bodies (cross points "
        "of bodies meeting at a corner inactive). cond: Lanczos estimate of the condition number; "
        "iter: Krylov iterations (stopping rule ||r_n||_2/||r_0||_2 < rtol); thesis: the value "
        f"printed in the thesis ({Path(sm.input.thesis).name}); dev.: (ours - thesis)/|thesis|. "
        f"{describe_constants(runs)}.\n\n")
    Path(sm.output.md).write_text(heading + to_markdown(table))
    Path(sm.output.tex).write_text(to_latex(table))
    print(to_markdown(table))
