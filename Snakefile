# ddsolve studies. Layout of results/ and reports/: README.md, "Running studies".
#   snakemake --cores 2                                   every study of config/default.yaml (the reproduction)
#   snakemake --cores 2 --configfile config/quick.yaml    the same studies, small (a smoke test)
#   snakemake --cores 2 --configfile config/table_4.yaml  one study (any single-study config)
#   snakemake --report reports/report.html                the HTML report of the last run, with captions
configfile: "config/default.yaml"


report: "workflows/report/workflow.rst"


#: Keys that make a config one study. Without them, `studies` lists the studies to run,
#: each a module of this workflow with its own config (workflows/rules/reproduce.smk).
ONE_STUDY_KEYS = ("study", "bench", "contact_scaling")


include: "workflows/rules/validate.smk"


if any(key in config for key in ONE_STUDY_KEYS):
    config.pop("studies", None)  # inherited from config/default.yaml by --configfile

    include: "workflows/rules/study.smk"

else:

    include: "workflows/rules/reproduce.smk"


rule all:
    input:
        targets(),
    default_target: True
