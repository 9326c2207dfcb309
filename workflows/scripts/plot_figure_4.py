"""Snakemake script of rule figure_4: summary CSV + thesis transcription -> <figure>.png.

Inputs from Snakemake: input.summary, input.thesis, output[0], params.figure
(FIGURES_4 entry: method, x, y, model, logx, title), params.contacts,
params.base (the base case the sweep starts from), log[0].
"""
import sys

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stdout = sys.stderr = log
    import pandas as pd

    from ddsolve.report.plots import plot_multibody_sweep

    sm = snakemake  # noqa: F821
    fig = sm.params.figure
    fits = plot_multibody_sweep(pd.read_csv(sm.input.summary), pd.read_csv(sm.input.thesis),
                                sm.output[0], method=fig["method"], x=fig["x"], y=fig["y"],
                                base=sm.params.base, model=fig["model"], contacts=sm.params.contacts,
                                logx=fig["logx"], title=fig["title"])
    for (label, who), (params, r2) in fits.items():
        print(f"{fig['model']} {label} {who}: params={tuple(round(p, 6) for p in params)} R2={r2:.4f}")
