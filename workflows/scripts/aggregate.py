"""Snakemake script of rule aggregate: result files (input) -> summary CSV (output[0])."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    from ddstudies.aggregate import collect, write_table

    df = collect(snakemake.input)  # noqa: F821
    write_table(df, snakemake.output[0])  # noqa: F821
    print(f"{len(df)} runs -> {snakemake.output[0]}")  # noqa: F821
