"""Snakemake script of rule bench_summary: case files (input) -> summary.csv and work_precision.csv."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    from ddstudies.bench.report import summary_table
    from ddstudies.aggregate import collect, write_table
    from ddstudies.workflow import write_manifest

    sm = snakemake  # noqa: F821
    df = collect(sm.input, quarantine=True)
    write_table(df, sm.output.summary)
    write_manifest([*sm.input, sm.output.summary], sm.output.manifest)
    table = summary_table(df)
    write_table(table, sm.output.table)
    print(table.to_string(), flush=True)

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
