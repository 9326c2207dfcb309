"""Snakemake script of rule contact_comparison: summary CSV -> comparison.md, .tex and .png.

Inputs from Snakemake: input.summary, input.table_5_1, input.table_6_1 (thesis
transcriptions), output.md, output.tex, output.png, log[0].
"""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.workflow import write_text
    from ddstudies.report.contact_plots import plot_method_comparison
    from ddstudies.report.contact_tables import render_comparison

    sm = snakemake  # noqa: F821
    theses = {"active-set": pd.read_csv(sm.input.table_5_1), "smalbe": pd.read_csv(sm.input.table_6_1)}
    from ddstudies.report.rule_sets import DEFAULT, chosen_rule_set, rule_sets

    summary = pd.read_csv(sm.input.summary)
    md, tex, table, caption = render_comparison(summary, theses)
    write_text(sm.output.md, md)
    write_text(sm.output.tex, tex)
    shown = chosen_rule_set(summary) if "preset" in summary.columns else DEFAULT
    several = "preset" in summary.columns and len(rule_sets(summary)) > 1
    plot_method_comparison(table, sm.output.png, caption=caption,     # name the rule set where it is not obvious
                           rule_set=shown if several or shown != DEFAULT else None)
    print(md)

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
