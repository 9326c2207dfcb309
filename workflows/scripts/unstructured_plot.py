"""Snakemake script of rule unstructured_plot: results/<study>/summary.csv -> reports/<study>/unstructured.png."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.bench.unstructured import plot_unstructured

    sm = snakemake  # noqa: F821
    df = pd.read_csv(sm.input[0])
    plot_unstructured(df, sm.output[0])
    print(f"{len(df)} runs -> {sm.output[0]}")
