"""Snakemake script of rule mpi_summary: case JSONs -> mpi.csv and mpi.md (speed-up, comm counts,
load average, and the alpha-beta model of ddsolve.parallel.model calibrated on the first case)."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import csv
    import json
    from pathlib import Path

    from ddsolve.parallel.model import mpi_report

    sm = snakemake  # noqa: F821
    runs = [json.loads(Path(path).read_text()) for path in sm.input]
    rows, text = mpi_report(runs)
    tmp = Path(sm.output.table + ".tmp")
    with open(tmp, "w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(sm.output.table)
    Path(sm.output.markdown + ".tmp").write_text(text)
    Path(sm.output.markdown + ".tmp").replace(sm.output.markdown)
    print(text, flush=True)
