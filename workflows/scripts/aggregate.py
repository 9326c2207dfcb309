"""Snakemake script of rule aggregate: result files (input) -> summary CSV (output[0])."""
import sys

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stdout = sys.stderr = log
    from ddsolve.io.aggregate import collect, write_table

    df = collect(snakemake.input)  # noqa: F821
    write_table(df, snakemake.output[0])  # noqa: F821
    print(f"{len(df)} runs -> {snakemake.output[0]}")  # noqa: F821
