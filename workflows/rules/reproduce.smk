# The reproduction: every study listed under `studies` (config/default.yaml: the
# thesis's Tables 4.1, 4.2, 5.1, 6.1 and Figures 4.2, 4.3, 5.2, then the
# work-precision, scaling and stress studies; config/quick.yaml: the same, small).
#
# Each entry names a single-study config file and, under `set`, keys that override
# it (merged as Snakemake merges several --configfile: mappings key by key, any
# other value replaced). The study then runs as a Snakemake module of this very
# workflow with that config, so its rules, paths, validation and reruns are those
# of `snakemake --configfile <that file>`: a study finished by either command is
# not rerun by the other. The module's rules are prefixed with the entry's name
# (`table_4_solve_case`, ...). The module and use-rule statements are written as
# the calls Snakemake compiles them to, so that the list of studies comes from the
# config.
import copy

import yaml
from snakemake.utils import update_config

# keys of a single study without `kind` and `study` land here, in the reproduction's config: say what is
# missing rather than that the studies list has unknown keys (a review)
_STUDY_KEYS = sorted(set(config) & {"methods", "problem", "subdomains", "elements", "sweeps", "bodies", "method"})
if _STUDY_KEYS:
    config_error(f"invalid config: kind: a single-study config names its kind and study (e.g. kind: grid, "
                 f"study: mine); got {', '.join(_STUDY_KEYS)} without them")
try:
    validate_config(config, "studies")
    studies_workflow.check_finite(config)      # its own max_memory: .nan was blamed on the first entry
except studies_workflow.ConfigError as err:
    config_error(str(err))


def study_config(entry):
    """The config of one `studies` entry: its configfile updated by its `set` mapping."""
    path = os.path.join(workflow.basedir, entry["configfile"])
    try:
        with open(path) as stream:
            study = studies_workflow.load_yaml_strict(stream) or {}     # a key given twice: refused
    except OSError as err:
        config_error(f"studies: {entry['name']}: cannot read configfile {entry['configfile']}: "
                            f"{err.strerror}")
    except (yaml.YAMLError, UnicodeDecodeError) as err:      # a traceback before (a review)
        why = str(err).splitlines()[0] if str(err) else type(err).__name__
        config_error(f"studies: {entry['name']}: configfile {entry['configfile']} is not valid YAML: {why}")
    except studies_workflow.ConfigError as err:
        config_error(f"invalid config: studies: {entry['name']}: configfile {entry['configfile']}: {err}")
    if not isinstance(study, dict):
        config_error(f"studies: {entry['name']}: configfile {entry['configfile']} must hold a YAML mapping of "
                     f"config keys, got a {type(study).__name__}")
    update_config(study, entry.get("set") or {})
    kind = study.get("kind")
    if "max_memory" in config and "max_memory" not in study and kind in studies_workflow.SCHEMAS:
        # the list's max_memory reaches every study whose kind checks case sizes (its schema has the key)
        if "max_memory" in studies_workflow.load_schema(schema_path(studies_workflow.SCHEMAS[kind]))["properties"]:
            study["max_memory"] = config["max_memory"]
    return study


STUDIES = [entry["name"] for entry in config["studies"]]
if len(set(STUDIES)) != len(STUDIES):
    config_error(f"studies: names must be unique, got {STUDIES}")
_OUTPUT_OF = {}      # two entries with one `study` would write the same results/<study>/ (Snakemake: ambiguous rules)
for entry in config["studies"]:
    _config = study_config(entry)
    try:        # each study's config, checked here so that an error names its entry
        validate_study(copy.deepcopy(_config))
    except studies_workflow.ConfigError as err:
        config_error(f"studies: {entry['name']} ({entry['configfile']}): {err}")
    _study = _config.get("study")
    if _study is not None and _study in _OUTPUT_OF:
        config_error(f"studies: {_OUTPUT_OF[_study]} and {entry['name']} both write study {_study!r} "
                            f"(results/{_study}/); give each entry its own `study`")
    _OUTPUT_OF[_study] = entry["name"]

for entry in config["studies"]:
    # module <name>: snakefile: "Snakefile"; config: study_config(entry)
    # use rule * from <name> as <name>_*
    workflow.module(entry["name"], snakefile=workflow.main_snakefile, config=study_config(entry))
    workflow.userule(rules=["*"], from_module=entry["name"], name_modifier=f"{entry['name']}_*")(lambda: None)


def targets():
    """The reports of every listed study (the inputs of their `all` rules)."""
    return [path for name in STUDIES for path in getattr(rules, f"{name}_all").input]
