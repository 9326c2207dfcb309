"""Snakemake script of rule stress_report: evaluate all stress records, write the report and the CSV.

Inputs from Snakemake: input (the series JSON files), output.md, output.csv, log[0].
"""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import pandas as pd

    from ddsolve.io.hdf5 import atomic_target
    from ddstudies.stress import evaluate, read_records, render_markdown
    from pathlib import Path

    rows = evaluate(read_records(list(snakemake.input)))  # noqa: F821
    md = Path(snakemake.output.md)  # noqa: F821
    with atomic_target(md) as tmp:
        tmp.write_text(render_markdown(rows))
    table = pd.DataFrame([{**{k: v for k, v in r.items() if k != "spec"},
                           **{f"spec_{k}": v for k, v in r["spec"].items()},
                           "nonfinite": " ".join(r["nonfinite"])} for r in rows])
    csv = Path(snakemake.output.csv)  # noqa: F821
    with atomic_target(csv) as tmp:
        table.to_csv(tmp, index=False)
    fails = [r["name"] for r in rows if r["outcome"] == "FAIL"]
    print(f"{len(rows)} cases, {len(fails)} FAIL: {' '.join(fails)}")

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
