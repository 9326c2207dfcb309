"""Snakemake script of rule table: summary CSV -> table.md and table.tex."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.workflow import write_text
    from ddstudies.report.tables import condition_table, describe_constants, label_presets, to_latex, to_markdown

    df, methods = label_presets(pd.read_csv(snakemake.input[0]), snakemake.params.methods)  # noqa: F821
    table = condition_table(df, methods=methods)
    study = snakemake.wildcards.study  # noqa: F821
    heading = (f"# Study `{study}`: condition number estimates and iterations\n\n"
               f"cond: Lanczos estimate of the condition number; iter: Krylov iterations; "
               f"1/H: subdomains per side; H/h: elements per subdomain side. "
               f"{describe_constants(df)}.\n\n")
    write_text(snakemake.output.md, heading + to_markdown(table))  # noqa: F821
    write_text(snakemake.output.tex, to_latex(table))  # noqa: F821
    print(to_markdown(table))

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
