"""Snakemake script of rule mpi_summary: case JSONs -> mpi.csv and mpi.md (speed-up, comm counts,
load average, and the alpha-beta model of ddsolve.parallel.model calibrated on the first Poisson case;
the contact case measured only)."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import csv
    import io

    from ddstudies.workflow import write_text
    from ddsolve.parallel.model import measured_report, mpi_report

    sm = snakemake  # noqa: F821
    from ddstudies.workflow import read_job_results

    runs = read_job_results(sm.input)        # checked: a corrupt one is moved aside, one line names it
    poisson = [run for run in runs if run["problem"] == "poisson"]
    contact = [run for run in runs if run["problem"] == "contact"]
    rows, text = mpi_report(poisson)
    rows = [{"problem": "poisson", "method": poisson[0]["method"], **row} for row in rows]
    if contact:
        contact_rows, contact_text = measured_report(contact)
        rows += contact_rows
        text += "\n## The active set method (contact problem (3.1))\n\n" + contact_text
    fields = list(dict.fromkeys(key for row in rows for key in row))
    table = io.StringIO(newline="")
    writer = csv.DictWriter(table, fieldnames=fields)
    writer.writeheader()
    writer.writerows(rows)
    write_text(sm.output.table, table.getvalue())
    write_text(sm.output.markdown, text)
    print(text, flush=True)

from ddstudies.report.html import write_twins  # noqa: E402

write_twins(snakemake.output)  # noqa: F821  (the HTML copies of the tables, for the report)
