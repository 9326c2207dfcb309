"""Snakemake script of rule unstructured_cond_law: results/<study>/cond/summary.csv -> cond_law.md (table and
fitted laws), cond_law.csv (one row per case and sweep), cond_law.png (log plot). params.cond_law: the config's
`cond_law` (its sweeps name the points); see ddstudies.bench.cond_law."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    from pathlib import Path

    from ddsolve.io.hdf5 import atomic_target
    from ddstudies.aggregate import read_table, write_table
    from ddstudies.bench.cond_law import cond_law_markdown, cond_law_summary, plot_cond_law

    sm = snakemake  # noqa: F821
    summary = cond_law_summary(read_table(sm.input[0]), dict(sm.params.cond_law))
    write_table(summary["table"], sm.output.table)
    text = cond_law_markdown(summary)
    with atomic_target(Path(sm.output.markdown)) as tmp:
        tmp.write_text(text)
    fig = plot_cond_law(summary, None)
    with atomic_target(Path(sm.output.plot)) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    print(text, flush=True)

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
