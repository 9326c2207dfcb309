# ddsolve studies. Layout of results/ and reports/: docs/studies.md.
#   snakemake --cores 2                                   every study of config/default.yaml (the reproduction)
#   snakemake --cores 2 --configfile config/quick.yaml    the same studies, small (a smoke test)
#   snakemake --cores 2 --configfile config/table_4.yaml  one study (any single-study config, with its `kind`)
#   snakemake --report reports/report.html                the HTML report of the last run, with captions
#   snakemake --lint                                      the workflow's lint (also run by .ci/run)
configfile: "config/default.yaml"


report: "workflows/report/workflow.rst"


include: "workflows/rules/validate.smk"


# Integrity of results (docs/studies.md, "Integrity of results"): the lock of a killed run is
# released; result files are checked before planning (a corrupt one is moved aside and
# recomputed) and validated when aggregated.
if MAIN_PROCESS:
    studies_workflow.release_stale_lock(log=lambda line: print(line, file=sys.stderr))


if "kind" in config or "study" in config:  # one study (workflows/rules/study.smk)
    config.pop("studies", None)  # inherited from config/default.yaml by --configfile

    include: "workflows/rules/study.smk"

else:  # the `studies` list (workflows/rules/reproduce.smk)

    include: "workflows/rules/reproduce.smk"


onstart:
    # the working directory is locked now: record by whom, remove the temporary files of killed writers
    studies_workflow.record_lock_owner(remote=not workflow.local_exec)
    for path in studies_workflow.remove_stale_tmp("results"):
        print(f"removed stale temporary file {path}", file=sys.stderr)


rule all:
    input:
        targets(),
    default_target: True
    localrule: True
