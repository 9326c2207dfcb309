"""Snakemake script of rule scaling_summary: case files -> summary.csv, scaling.csv (table) and scaling.md
(table, exponent fits, targets). params.targets: see ddstudies.bench.scaling.scaling_summary."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821

    from ddstudies.workflow import write_text
    from ddstudies.bench.scaling import scaling_summary, summary_markdown
    from ddstudies.aggregate import collect, write_table
    from ddstudies.workflow import write_manifest

    sm = snakemake  # noqa: F821
    df = collect(sm.input, quarantine=True)
    write_table(df, sm.output.summary)
    write_manifest([*sm.input, sm.output.summary], sm.output.manifest)
    summary = scaling_summary(df, dict(sm.params.targets))
    write_table(summary["table"], sm.output.table)
    text = summary_markdown(summary)
    write_text(sm.output.markdown, text)
    print(text, flush=True)

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
