"""Snakemake script of rule plot_cond: summary CSV -> cond_vs_Hh.png."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.report.plots import plot_cond_vs_Hh
    from ddstudies.report.tables import label_presets

    df, methods = label_presets(pd.read_csv(snakemake.input[0]), snakemake.params.methods)  # noqa: F821
    presets = sorted(set(df["preset"].astype(str))) if "preset" in df.columns else ["default"]
    feti = "feti" in set(df["method"].astype(str))       # the projection note only where FETI is drawn
    rules = (("ddsolve's default rules" + (" (FETI: the Q-weighted projection)" if feti else ""))
             if presets == ["default"] else "rule sets " + ", ".join(presets))      # the rules of the numbers
    fits = plot_cond_vs_Hh(df, snakemake.output[0], methods=methods,  # noqa: F821
                           title=f"Study {snakemake.wildcards.study}: cond vs H/h, {rules}")  # noqa: F821
    for (method, ns), (c, r2) in fits.items():
        print(f"{method} 1/H={ns}: C={c:.4g} R2={r2:.4f}")
