"""Snakemake script of rule bench_summary: case files (input) -> summary.csv and work_precision.csv."""
import sys

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stdout = sys.stderr = log
    from ddsolve.bench.report import summary_table
    from ddsolve.io.aggregate import collect, write_table

    sm = snakemake  # noqa: F821
    df = collect(sm.input)
    write_table(df, sm.output.summary)
    table = summary_table(df)
    write_table(table, sm.output.table)
    print(table.to_string(), flush=True)
