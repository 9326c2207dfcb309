"""Snakemake script of rule aggregate: result files (input), each validated -> summary CSV (output.summary)
and the SHA-256 of each, the summary's last (output.manifest). A corrupt file fails the job with one line naming it, and is
moved aside (<file>.corrupt) so that the next run recomputes it."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    from ddstudies.aggregate import collect, write_table
    from ddstudies.workflow import write_manifest

    df = collect(snakemake.input, quarantine=True)  # noqa: F821
    write_table(df, snakemake.output.summary)  # noqa: F821
    write_manifest([*snakemake.input, snakemake.output.summary], snakemake.output.manifest)  # noqa: F821
    print(f"{len(df)} runs -> {snakemake.output.summary}")  # noqa: F821
