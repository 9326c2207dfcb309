# ddsolve studies: one job per case, then a summary table and plots.
# Usage: snakemake --cores 4 [--configfile config/quick.yaml | config/table_4.yaml | config/table_5_6.yaml]
# Layout of results/ and reports/: README.md, "Running studies".
from snakemake.utils import validate


configfile: "config/default.yaml"
include: "workflows/rules/bench.smk"
include: "workflows/rules/scaling.smk"


validate(config, "workflows/schemas/config.schema.yaml")


include: "workflows/rules/common.smk"
include: "workflows/rules/solve.smk"
include: "workflows/rules/aggregate.smk"
include: "workflows/rules/report.smk"
include: "workflows/rules/multibody.smk"
include: "workflows/rules/stress.smk"
include: "workflows/rules/contact.smk"


rule all:
    input:
        report_files(),
