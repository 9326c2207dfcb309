"""Snakemake script of rule unstructured_summary: job CSVs -> summary.csv, unstructured.csv (table) and
unstructured.md (table, exponent fits, targets). params.targets: see
ddstudies.bench.unstructured.unstructured_summary."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821

    import pandas as pd

    from ddstudies.workflow import write_text
    from ddstudies.aggregate import write_table
    from ddstudies.bench.unstructured import summary_markdown, unstructured_summary

    sm = snakemake  # noqa: F821
    from ddstudies.workflow import read_job_results

    df = pd.concat(read_job_results(sm.input), ignore_index=True)     # checked, as the HDF5 results
    write_table(df, sm.output.summary)
    summary = unstructured_summary(df, dict(sm.params.targets))
    write_table(summary["table"], sm.output.table)
    text = summary_markdown(summary)
    write_text(sm.output.markdown, text)
    print(text, flush=True)

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
