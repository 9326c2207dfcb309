"""Snakemake script of rule figure_4: summary CSV + thesis transcription(s) -> <figure>.png.

Inputs from Snakemake: input.summary, input.thesis (one path or a list), output[0],
params.figure (FIGURES_4 entry: method, x, y, model, logx, title; kind "growth" for
the FETI-FETI / hybrid iterations against H_b/H_s, with thesis = [table 4.1, table 4.2]),
params.contacts, params.base (the base case the sweep starts from), log[0].
"""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddstudies.report.plots import plot_iterations_vs_HbHs, plot_multibody_sweep

    sm = snakemake  # noqa: F821
    fig = sm.params.figure
    thesis_paths = [sm.input.thesis] if isinstance(sm.input.thesis, str) else list(sm.input.thesis)
    theses = [pd.read_csv(path) for path in thesis_paths]
    df = pd.read_csv(sm.input.summary)
    if fig.get("kind") == "growth":
        fits = plot_iterations_vs_HbHs(df, dict(zip(["feti-feti", "hybrid"], theses)), sm.output[0],
                                       base=sm.params.base, contacts=sm.params.contacts,
                                       title=fig.get("title"))
        for (case, method), (params, r2) in fits.items():
            print(f"{case} {method}: a, b = {tuple(round(p, 6) for p in params)} R2={r2:.4f}")
    else:
        fits = plot_multibody_sweep(df, theses[0], sm.output[0], method=fig["method"], x=fig["x"],
                                    y=fig["y"], base=sm.params.base, model=fig["model"],
                                    contacts=sm.params.contacts, logx=fig["logx"], title=fig["title"])
        for (label, who), (params, r2) in fits.items():
            print(f"{fig['model']} {label} {who}: params={tuple(round(p, 6) for p in params)} R2={r2:.4f}")
