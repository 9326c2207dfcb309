"""Snakemake script of rule contact_table: summary CSV + thesis transcription -> <table>.md and .tex.

Inputs from Snakemake: input.summary, input.thesis, output.md, output.tex,
wildcards.table (table_5_1 or table_6_1), log[0].
"""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.workflow import write_text
    from ddstudies.report.contact_tables import render_contact_table

    sm = snakemake  # noqa: F821
    md, tex = render_contact_table(pd.read_csv(sm.input.summary), pd.read_csv(sm.input.thesis),
                                   sm.wildcards.table)
    write_text(sm.output.md, md)
    write_text(sm.output.tex, tex)
    print(md)

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
