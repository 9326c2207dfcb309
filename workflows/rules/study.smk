# One study: the rules of the study kinds present in the config. A config may hold
# a `study` (problem poisson / multibody / contact, or a stress study), a `bench`
# mapping and a `contact_scaling` mapping; `targets()` (rule all) asks for the
# reports of each one present.
include: "bench.smk"
include: "scaling.smk"

if "study" in config:
    validate_config(config, "config")

    if config["study"].startswith("stress"):  # a catalog of cases, not a grid

        include: "stress.smk"

    else:

        include: "common.smk"
        include: "solve.smk"
        include: "aggregate.smk"
        include: "report.smk"
        include: "multibody.smk"
        include: "contact.smk"


def targets():
    """The reports of every study kind in the config (the input of rule all)."""
    files = report_files() if "study" in config else []
    if BENCH is not None:
        files += bench_targets()
    if SCALING is not None:
        files += scaling_targets()
    return files
