# validate_config: the config against a schema of workflows/schemas/ with the option
# lists of ddsolve.options injected (ddstudies.workflow.load_schema), filling in the
# schema's defaults; a short error that names the offending key.
import os
import sys

from ddstudies import workflow as studies_workflow


def _main_process():
    """True in the Snakemake process that plans the run (not in a cluster job re-reading the workflow)."""
    try:
        return bool(workflow.is_main_process)
    except Exception:  # an older Snakemake or settings not set: the plain run
        return True


#: Integrity actions (locks, incomplete marks, moving corrupt results aside) happen only here.
MAIN_PROCESS = _main_process()

#: Snakemake's options that run no job and only read the workflow and its files: with them the integrity
#: actions are not taken (a review: --lint and --summary after a truncated result moved it aside and
#: deleted the summary and the reports, then ran nothing; --report did the same and then failed).
READ_ONLY_OPTIONS = ("--lint", "--summary", "-S", "--detailed-summary", "-D", "--report", "--list", "-l",
                     "--list-target-rules", "--lt", "--dag", "--rulegraph", "--filegraph", "--d3dag",
                     "--list-changes", "--lc", "--list-input-changes", "--li", "--list-params-changes", "--lp",
                     "--list-code-changes", "--list-version-changes", "--print-compilation", "--containerize",
                     "--export-cwl", "--archive")


#: The same options as attributes of Snakemake's parsed command line (which resolves abbreviations such as
#: ``--summ``, as Snakemake itself does; a review).
READ_ONLY_ARGS = ("lint", "summary", "detailed_summary", "report", "list_rules", "list_target_rules", "dag",
                  "rulegraph", "filegraph", "d3dag", "list_changes", "list_input_changes", "list_params_changes",
                  "list_untracked", "print_compilation", "containerize", "export_cwl", "archive")


def _read_only():
    """Whether this Snakemake was started with an option of READ_ONLY_OPTIONS: read from Snakemake's own parser
    (abbreviations included), else (another entry point, an argv it does not parse) by the exact names."""
    try:
        from snakemake.cli import get_argument_parser

        args, _ = get_argument_parser().parse_known_args(sys.argv[1:])
        return any(getattr(args, name, None) not in (None, False) for name in READ_ONLY_ARGS)
    except (Exception, SystemExit):
        return any(arg.split("=", 1)[0] in READ_ONLY_OPTIONS + ("--list-untracked", "--lu") for arg in sys.argv[1:])


READ_ONLY = MAIN_PROCESS and _read_only()     # (jobs never take the actions anyway)


def config_error(message):
    """Bad configuration: one line ``ddsolve: error: <message>`` on stderr and exit status 2, before any job
    runs, as the command line answers bad input (a WorkflowError came with Snakemake's header and three
    or four lines of its call stack; a review)."""
    sys.stderr.write(f"ddsolve: error: {message}\n")
    sys.stderr.flush()
    sys.exit(2)


# a key given twice in a config file: YAML keeps the last one without a word (a review: `methods:` twice ran
# the second list only); Snakemake has loaded the files already, so they are read again here, strictly
if MAIN_PROCESS:
    try:
        studies_workflow.check_config_files(getattr(workflow, "configfiles", ()))
    except studies_workflow.ConfigError as _err:
        config_error(str(_err))


def schema_path(schema):
    return os.path.join(workflow.basedir, "workflows", "schemas", f"{schema}.schema.yaml")


def validate_config(data, schema, key="config"):
    """Validate `data` against workflows/schemas/<schema>.schema.yaml, filling in defaults.

    Raises ConfigError("invalid <key> (<schema>.schema.yaml): <path>: <what is wrong>") (the caller
    reports it with config_error, adding where it comes from).
    """
    studies_workflow.validate(data, schema_path(schema), key=key)


def validate_study(data):
    """Validate a single-study config against the schema of its `kind`; the kind.

    Numbers must be finite (YAML .nan / .inf are refused, naming the key), and integral floats
    become ints after validation (studies_workflow.canonical_numbers); the cases themselves are checked
    through ddsolve.spec.ProblemSpec in common.smk. Raises ConfigError.
    """
    studies_workflow.check_finite(data)
    kind = data.get("kind")
    if kind not in studies_workflow.SCHEMAS:
        raise studies_workflow.ConfigError(f"invalid config: kind: {kind!r} is not one of "
                                           f"{list(studies_workflow.SCHEMAS)} (every single-study config "
                                           f"names its kind)")
    # the kinds of the three grid studies and their problems (the schema's first complaint was another key's:
    # "'thesis_tables' is a required property" for kind grid with problem multibody; a review)
    problem_kind = {"poisson": "grid", "multibody": "table_4", "contact": "contact"}
    problem = data.get("problem")
    if kind in problem_kind.values() and problem in problem_kind and problem_kind[problem] != kind:
        raise studies_workflow.ConfigError(
            f"invalid config: problem: {problem!r} is a study of kind {problem_kind[problem]!r}, not {kind!r} "
            f"(kind grid: poisson; table_4: multibody; contact: contact)")
    sweeps = data.get("sweeps")
    if "bodies" in data and isinstance(sweeps, list) and sweeps and all(
            isinstance(sweep, dict) and "bodies" in sweep for sweep in sweeps):
        # the top-level bodies is only the default of a sweep without its own (a review: it was ignored)
        raise studies_workflow.ConfigError("invalid config: bodies: every sweep gives its own bodies, so this "
                                           "one is not used; give it in the sweeps")
    validate_config(data, studies_workflow.SCHEMAS[kind])
    # again after the schema step, which reads strings such as "nan" (from --config or YAML 1.1) as numbers
    # (a review: rtols [1e-2, nan] planned its jobs)
    studies_workflow.check_finite(data)
    studies_workflow.canonical_numbers(data)   # gamma: 1.0 and gamma: 1 are the same params (no rerun)
    return kind


def checked_cases(cases):
    """check_cases (ddstudies.workflow), a failure reported by config_error: {label: size Estimate} of
    (label, spec) pairs."""
    try:
        return studies_workflow.check_cases(cases, max_memory=config.get("max_memory"))
    except studies_workflow.ConfigError as err:
        config_error(str(err))


def check_result_files(paths, summary=None, consumers=(), manifest=None):
    """Before planning: clear the "incomplete" marks that an interrupted run left on complete results
    (ddstudies.workflow.release_complete); move truncated / non-HDF5 results aside (<file>.corrupt); if
    a result the summary was built from is missing, remove the summary and its consumers, so that this
    run rebuilds them and the result (ddstudies.workflow.check_results). Not for a command that only reads
    (READ_ONLY: --lint, --summary, --report, ...)."""
    if not MAIN_PROCESS or READ_ONLY:
        return
    paths = list(paths)
    studies_workflow.release_complete(paths, log=lambda line: print(line, file=sys.stderr))
    studies_workflow.check_results(paths, summary, consumers, manifest=manifest,
                                   log=lambda line: print(line, file=sys.stderr))
