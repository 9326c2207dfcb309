"""Snakemake script of rule scaling_plot: results/<study>/summary.csv -> reports/<study>/scaling.png."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.bench.scaling import plot_scaling

    sm = snakemake  # noqa: F821
    df = pd.read_csv(sm.input[0])
    plot_scaling(df, sm.output[0])
    print(f"{len(df)} cases -> {sm.output[0]}")
