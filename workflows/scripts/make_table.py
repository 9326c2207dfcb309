"""Snakemake script of rule table: summary CSV -> table.md and table.tex."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.workflow import write_text
    from ddstudies.report.rule_sets import NOTE_MARK, only_sentence, rule_sets
    from ddstudies.report.tables import condition_table, describe_constants, label_presets, to_latex, to_markdown

    runs = pd.read_csv(snakemake.input[0])  # noqa: F821
    ran = rule_sets(runs)               # one rule set: named once here; several: in the column headers
    df, methods = label_presets(runs, snakemake.params.methods)  # noqa: F821
    table = condition_table(df, methods=methods)
    study = snakemake.wildcards.study  # noqa: F821
    heading = (f"# Study `{study}`: condition number estimates and iterations\n\n"
               f"cond: Lanczos estimate of the condition number; iter: Krylov iterations; "
               f"1/H: subdomains per side; H/h: elements per subdomain side. "
               f"{describe_constants(df)}.\n\n"
               + (f"{NOTE_MARK} {only_sentence(ran[0])}\n\n" if len(ran) == 1 else ""))
    write_text(snakemake.output.md, heading + to_markdown(table))  # noqa: F821
    write_text(snakemake.output.tex, to_latex(table))  # noqa: F821
    print(to_markdown(table))

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
