"""Snakemake script of rule bench_plot: work_precision.csv -> work_precision.png (params.time: wall or cpu)."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.bench.report import plot_work_precision

    sm = snakemake  # noqa: F821
    df = pd.read_csv(sm.input[0])
    plot_work_precision(df, sm.output[0], time=sm.params.time)
    print(f"{len(df)} cases -> {sm.output[0]}")
