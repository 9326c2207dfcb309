# Helpers shared by the rules of one study (included by study.smk after validation):
# the case list, the parameters of one case and the targets, per study kind. Every
# setting comes from the validated config; rule files hold rules only.
# Grid kinds: paths depend only on a case's keys (study, method, [contact, bodies,]
# subdomains, elements, rule set); all other parameters travel in `params`, so Snakemake's
# params rerun-trigger reruns exactly the cases whose parameters changed. Rule sets
# (config `presets`): the default's path has no suffix (the paths of runs made before
# `presets` existed), any other preset's ends in _<preset> (Ns4_m8_thesis.h5).
import itertools
import re
from dataclasses import asdict
from types import SimpleNamespace

#: Kinds whose cases are a grid solved by rule solve_case (solve.smk) and aggregated.
GRID_KINDS = ("grid", "table_4", "contact")

#: Resources of the jobs that only read results and write tables, figures and summaries
#: (the solves' come from ddsolve.limits.estimate: ddstudies.workflow.case_mem_mb, case_runtime).
REPORT_MEM_MB = 2000
REPORT_RUNTIME = 15

STUDY = config["study"]
MULTIBODY = KIND == "table_4"
CONTACT = KIND == "contact"

#: Config keys shared by every case, passed unchanged to ddsolve.spec.ProblemSpec
#: (a multibody case overrides `bodies` with its own value and adds `contact`).
from ddsolve.spec import COND_METHODS  # noqa: E402  (methods with a Lanczos estimate)

SHARED_SPEC_KEYS = ("problem", "bodies", "rho", "f", "scaling", "gamma", "norm", "projection", "rtol", "maxiter",
                    "cond", "check", "preset")


def _as_list(value):
    return list(value) if isinstance(value, (list, tuple)) else [value]


def study_cases():
    """The (bodies, subdomains, elements) triples of the study, in config order, no duplicates.

    With `sweeps`: the union of the grids bodies x subdomains x elements of the
    sweeps, in the order listed; otherwise the one grid of the top-level keys.
    """
    sweeps = config.get("sweeps") or [
        {"bodies": config.get("bodies", 1), "subdomains": config["subdomains"],
         "elements": config["elements"]}]
    cases = {}
    for sweep in sweeps:
        grid = itertools.product(_as_list(sweep.get("bodies", config.get("bodies", 1))),
                                 _as_list(sweep["subdomains"]), _as_list(sweep["elements"]))
        cases.update(dict.fromkeys(tuple(int(v) for v in case) for case in grid))
    cases = list(cases)
    if CONTACT:  # two membranes, not a grid axis (the case paths have no bodies)
        cases = list(dict.fromkeys((1, s, m) for _, s, m in cases))
    elif not MULTIBODY and any(b != 1 for b, _, _ in cases):
        config_error("config: problem 'poisson' has exactly one body; use kind table_4 (problem "
                            "multibody) to sweep over bodies")
    return cases


def study_presets():
    """The presets (ddsolve.presets, the rule sets) the study sweeps, from config `presets`, no duplicates.

    A study that sets the single key `preset` and leaves `presets` at its default
    ([default]) runs that one preset; setting both, `preset` must be in `presets`.
    """
    presets = list(dict.fromkeys(config.get("presets", ["default"])))
    if "preset" in config:
        if presets == ["default"]:
            return [config["preset"]]
        if config["preset"] not in presets:
            config_error(f"invalid config: preset: {config['preset']!r} is not in presets {presets}")
    return presets


def preset_tag(preset):
    """The case-path suffix of a preset, none for the default and _<preset> otherwise."""
    return "" if preset == "default" else f"_{preset}"


def tag_preset(tag):
    """The rule set of a case-path suffix (inverse of preset_tag)."""
    return tag[1:] if tag else "default"


def shared_spec(method, exclude=()):
    """The study's keys of SHARED_SPEC_KEYS for a case of ``method``: a study's ``cond`` (default true) asks
    for the Lanczos estimates of the methods that have them (COND_METHODS), and the others run without."""
    spec = {key: config[key] for key in SHARED_SPEC_KEYS if key in config and key not in exclude}
    if spec.get("cond") and method not in COND_METHODS:
        del spec["cond"]
    # ProblemSpec's defaults written out are no change: params as without them (a review: norm: l2 or
    # projection: orthogonal in a config reran every finished case with identical results)
    for key, default in (("norm", "l2"), ("projection", "orthogonal")):
        if str(spec.get(key, default)).lower() == default:
            spec.pop(key, None)
    return spec


def case_spec(wildcards):
    """The ProblemSpec mapping of one case (a plain dict: a params value)."""
    spec = shared_spec(wildcards.method, exclude=("preset",))
    spec.update(method=wildcards.method, subdomains=int(wildcards.subdomains),
                elements=int(wildcards.elements))
    preset = tag_preset(wildcards.preset_tag)
    if preset != "default":      # the default, also written out: params as before `presets` (no rerun)
        spec["preset"] = preset
    if MULTIBODY:
        spec.update(bodies=int(wildcards.bodies), contact=wildcards.contact)
    else:
        spec["bodies"] = 2 if CONTACT else 1   # contact: the two membranes of (3.1)
    return spec


def _case_specs():
    """(result path, ProblemSpec mapping) of every case of the study."""
    out = []
    for path in case_files():
        wc = _case_wildcards(path)
        out.append((path, case_spec(wc)))
    return out


def _case_wildcards(path):
    """The wildcards of a case path (results/<CASE>.h5) as an object with attributes."""
    pattern = re.escape(f"results/{CASE}.h5").replace(r"\{", "{").replace(r"\}", "}")
    regex = re.sub(r"\{(\w+)\}", r"(?P<\1>[^/]+?)", pattern).replace(
        "(?P<preset_tag>[^/]+?)", "(?P<preset_tag>(?:_[^/]+)?)")   # the default's suffix is empty
    return SimpleNamespace(**re.fullmatch(regex, path).groupdict())


def case_size(wildcards):
    """The size estimate (ddsolve.limits.Estimate) of the case of a solve_case job."""
    return CASE_SIZES[f"results/{CASE}.h5".format(**dict(wildcards.items()))]


def case_files(wildcards=None):
    """All result files of the configured study."""
    contacts = CONTACTS or [None]
    return [f"results/{CASE}.h5".format(study=STUDY, method=method, contact=contact, bodies=b,
                                        subdomains=s, elements=m, preset_tag=preset_tag(preset))
            for preset in PRESETS for method in config["methods"] for contact in contacts for b, s, m in CASES]


def thesis_table(name):
    """Path of a thesis transcription (config key thesis_tables); a missing one is a config error while planning
    (it was Snakemake's MissingInputException of a report job)."""
    folder = config["thesis_tables"]
    path = f"{folder}/{name}.csv"
    if not os.path.isfile(path):
        have = sorted(f[:-4] for f in os.listdir(folder) if f.endswith(".csv")) if os.path.isdir(folder) else None
        config_error(f"invalid config: thesis_tables: no transcription {name!r} in {folder!r} "
                            + (f"(it has {have}); a table's name or its `thesis` key names one" if have is not None
                               else "(no such folder)"))
    return path


def thesis_inputs(entry, default, keys=()):
    """The thesis transcriptions of a `tables` / `figures` entry ("thesis": a name or a list).

    ``keys``: header columns each transcription must have; one without them is a config error
    while planning (a review: `thesis: table_5_1` for a Chapter 4 table failed its report job
    with a KeyError after every solve had run).
    """
    names = entry.get("thesis", default)
    names = [names] if isinstance(names, str) else list(names)
    paths = [thesis_table(name) for name in names]
    for name, path in zip(names, paths):
        with open(path, encoding="utf-8", errors="replace") as handle:
            header = [column.strip() for column in handle.readline().split(",")]
        missing = [key for key in keys if key not in header]
        if missing:
            config_error(f"invalid config: thesis: the transcription {name!r} ({path}) has no column "
                         f"{', '.join(missing)}: not one of the multibody tables 4.1 / 4.2")
    return paths


#: The row keys of a Chapter 4 transcription (ddstudies.report.tables.THESIS_KEYS).
MULTIBODY_THESIS_KEYS = ("inv_Hb", "Hb_over_Hs", "Hs_over_h")


def table_4_params(name):
    """The `tables` entry ``name`` as the table_4 script reads it (a params value).

    With ``cond: false`` the study has no condition estimates: ``cond`` leaves the entry's
    quantities and ``cond: false`` is added, so that the table has no column of dashes and its
    legend says why (a review). With estimates the entry is unchanged (no rerun of finished tables).
    """
    entry = dict(config["tables"][name])
    if not config.get("cond", True):
        entry["quantities"] = [q for q in entry.get("quantities", ["cond", "iterations"]) if q != "cond"]
        entry["cond"] = False
    return studies_workflow.sorted_keys(entry)


def figure_5_2_spec():
    """The ProblemSpec mapping of Figure 5.2: the study's shared keys, the case of `figure_5_2`."""
    spec = shared_spec(config["figure_5_2"]["method"])
    spec.update(problem="contact", bodies=2, **config["figure_5_2"])
    presets = study_presets()
    # a study of one preset shows that preset's solution (a review: `presets: [thesis]` drew the default
    # rules' Figure 5.2); with several, the default's, named in the title
    if len(presets) == 1 and presets[0] != "default":
        spec["preset"] = presets[0]
    return studies_workflow.sorted_keys(spec)


def thesis_coefficients():
    """Whether the study solves with the thesis's coefficient, scaling and hybrid rules (rho = 1, rho-scaling,
    gamma = 1, norm l2, the orthogonal projection).

    The evidence reports (Table 4.1 readings, Table 4.2 optimal, the contact work-precision report) run
    their own solves with those, whatever the study's keys say; for another coefficient or rule their numbers
    would not be the study's, so they are made only for this one (docs/studies.md; a review: a study with
    norm: M got a Table 4.2 evidence report solved in the l2 norm under its name).
    """
    return (str(config.get("rho", 1)) in ("1", "1.0") and config.get("scaling", "rho") == "rho"
            and float(config.get("gamma", 1)) == 1.0 and str(config.get("norm", "l2")).lower() == "l2"
            and str(config.get("projection", "orthogonal")).lower() == "orthogonal")


def grid_report_files():
    """The reports of a grid study (kind grid, table_4 or contact)."""
    methods = set(config["methods"])
    evidence = thesis_coefficients()
    if KIND == "grid":     # the cond plot only where a method has Lanczos estimates (cond: false has none)
        plot = config.get("cond", True) and bool(methods & set(COND_METHODS))
        return [f"reports/{STUDY}/table.md", f"reports/{STUDY}/table.tex"] + (
            [f"reports/{STUDY}/cond_vs_Hh.png"] if plot else [])
    files = []
    for name, table in config["tables"].items():
        if table["method"] in methods:
            files += [f"reports/{STUDY}/{name}.md", f"reports/{STUDY}/{name}.tex"]
    if MULTIBODY:
        # a figure of condition estimates has none of ours with cond: false (it showed the thesis's points
        # only; a review): not made, as the grid study's cond plot
        files += [f"reports/{STUDY}/{name}.png" for name, fig in config["figures"].items()
                  if fig["method"] in methods and (fig.get("y") != "cond" or config.get("cond", True))]
        if "hybrid" in methods and evidence:   # Table 4.2 evidence (multibody.smk, rule table_4_2_optimal)
            files.append(f"reports/{STUDY}/table_4_2_optimal.md")
        if "feti-feti" in methods and evidence:   # Table 4.1 readings (multibody.smk, rule table_4_1_readings)
            files.append(f"reports/{STUDY}/table_4_1_readings.md")
        return files
    if {"active-set", "smalbe"} <= methods:
        files += [f"reports/{STUDY}/comparison.{ext}" for ext in ("md", "tex", "png")]
        if evidence:
            files += [f"reports/{STUDY}/work_precision.{ext}" for ext in ("md", "png")]   # contact.smk
    files += [f"reports/{STUDY}/figure_5_2_{part}" for part in ("surface.png", "contact.png", "contact.csv")]
    return files


if KIND in GRID_KINDS:
    #: One case's path below results/ and logs/ (without the suffix).
    if MULTIBODY:
        CASE = "{study}/{method}/{contact}/Nb{bodies}_Ns{subdomains}_m{elements}{preset_tag}"
    else:
        CASE = "{study}/{method}/Ns{subdomains}_m{elements}{preset_tag}"
    PRESETS = study_presets()
    CASES = study_cases()
    CONTACTS = list(config.get("contacts", [])) if MULTIBODY else []
    if MULTIBODY:        # the thesis transcriptions that the tables and figures name exist (multibody.smk's inputs)
        for _table, _entry in config["tables"].items():
            thesis_inputs(_entry, _table, MULTIBODY_THESIS_KEYS)
        for _entry in config["figures"].values():
            if "thesis" in _entry:
                thesis_inputs(_entry, None, MULTIBODY_THESIS_KEYS)
    # Every case is a valid ProblemSpec that fits the machine, before any job runs.
    CASE_SIZES = checked_cases(_case_specs())
    if CONTACT:
        FIGURE_5_2_SIZE = checked_cases([("figure_5_2", figure_5_2_spec())])["figure_5_2"]

    wildcard_constraints:
        study=re.escape(STUDY),
        method="|".join(re.escape(m) for m in config["methods"]),
        contact="|".join(re.escape(c) for c in CONTACTS) or "full",
        bodies=r"[1-9]\d*",
        subdomains=r"[1-9]\d*",
        elements=r"[1-9]\d*",
        preset_tag="(?:" + "|".join(re.escape(preset_tag(p)) for p in PRESETS) + ")",   # "" (default) or _<preset>


# --- kind bench (bench.smk) --------------------------------------------------------------
# Jobs: per problem kind, one reference (direct solves of the problem and of its 2x
# refinement), then one job per (method, rtol) and per peer (the direct peer once,
# pyamg per rtol); then a summary CSV and the plot. Tolerance labels (rtol1e-06, ...)
# name the job outputs: two rtols with the same label are refused.


def _bench_cases():
    """(problem, solver, tol label) of every case, in config order."""
    from ddstudies.bench.methods import get_method

    cases = []
    for kind, prob in config["problems"].items():
        for key in ("methods", "peers"):
            for name in prob.get(key, []):
                try:
                    get_method(name, kind)
                except KeyError as err:
                    config_error(f"invalid config: problems: {kind}: {key}: {err.args[0]}")
        for name in list(prob.get("methods", [])) + list(prob.get("peers", [])):
            if get_method(name, kind).iterative:
                cases += [(kind, name, tol) for tol in BENCH_RTOLS]
            else:
                cases.append((kind, name, "exact"))
    return cases


def bench_spec(wildcards):
    """ProblemSpec mapping of a problem kind (plain dict: a params value)."""
    prob = config["problems"][wildcards.kind]
    return studies_workflow.sorted_keys({**prob["spec"], "problem": wildcards.kind, "maxiter": config["maxiter"]})


def bench_reference_spec(wildcards):
    """:func:`bench_spec` without maxiter: the direct reference does not iterate, so a new maxiter must not
    rerun it (Snakemake's params rerun-trigger)."""
    return {key: value for key, value in bench_spec(wildcards).items() if key != "maxiter"}


def bench_options(wildcards=None):
    return {key: config[key] for key in ("maxiter", "threads", "direct", "repeats")}


def bench_case_files(wildcards=None):
    return [f"results/{STUDY}/{kind}/{solver}/{tol}.h5" for kind, solver, tol in BENCH_CASES]


if KIND == "bench":
    from ddsolve.spec import ProblemSpec
    from ddstudies.bench.peers import available_direct_solvers
    from ddstudies.bench.problems import check_load_cells

    if MAIN_PROCESS and config["direct"] not in available_direct_solvers():   # not after the first job
        config_error(f"invalid config: direct: backend {config['direct']!r} is not installed here "
                     f"(available: {', '.join(available_direct_solvers())})")

    try:
        BENCH_RTOLS = studies_workflow.bench_rtols(config["rtols"])
    except studies_workflow.ConfigError as err:
        config_error(f"invalid config: {err}")
    BENCH_CASES = _bench_cases()
    BENCH_PROBLEMS = "|".join(re.escape(k) for k in config["problems"])
    # each problem's spec: a valid ProblemSpec that fits the machine (the reference solves its 2x refinement)
    BENCH_SIZES = {label.split("/")[1]: size for label, size in checked_cases(
        (f"problems/{kind}/spec", bench_spec(SimpleNamespace(kind=kind))) for kind in config["problems"]).items()}
    for _kind, _prob in config["problems"].items():   # a load grid the mesh resolves (ddstudies.bench.problems)
        try:
            check_load_cells(ProblemSpec.from_mapping(bench_spec(SimpleNamespace(kind=_kind))), _prob.get("load_cells"))
        except ValueError as err:
            config_error(f"invalid config: problems: {_kind}: {err}")


# --- kind scaling (scaling.smk) -------------------------------------------------------------
# One job per (method, H/h), each taking all the cores given to Snakemake so that cases
# run one at a time; then the summary, the plot and a cProfile of one solve.


def scaling_threads(wildcards):
    """All the cores given to Snakemake, so that the timed cases run one at a time
    (1 where no --cores is given, as for --report or a cluster run). In a cluster job
    (remote mode, run with --cores all) the cores its submitter asked for: the node's
    count would exceed the job's allocation (srun: More processors requested than permitted)."""
    if workflow.remote_exec:
        return int(os.environ.get("SLURM_CPUS_PER_TASK", 1))
    try:
        return workflow.cores
    except WorkflowError:
        return 1


def scaling_case_files(wildcards=None):
    return [f"results/{STUDY}/{method}/N{config['subdomains']}_m{m}.h5"
            for method in config["methods"] for m in config["elements"]]


#: Options of a scaling case that each method reads (the direct reference ignores rtol and maxiter,
#: ddsolve's method the direct backend): a change of another method's option reruns nothing.
SCALING_OPTIONS = {"active-set": (("rtol", 1e-5), ("maxiter", 1000)),
                   "smalbe": (("rtol", 1e-5), ("maxiter", 1000)),
                   "pdas": (("direct", "mkl-pardiso"), ("direct_threads", 1))}


def scaling_options(wildcards, method=None):
    """The options of a scaling case (``method``: the wildcard's, else the profiled method's)."""
    method = method or getattr(wildcards, "method", None) or SCALING_PROFILE.get("method", "active-set")
    keys = SCALING_OPTIONS.get(method, ()) + (("repeats", 1), ("repeat_budget", 30.0))
    return {key: config.get(key, default) for key, default in keys}


def scaling_mem_mb(wildcards):
    """mem_mb of a scaling job: the estimate of its contact problem (method active-set; pdas is alike)."""
    elements = int(getattr(wildcards, "m", SCALING_PROFILE["elements"]))
    return studies_workflow.case_mem_mb(SCALING_SIZES[elements], factor=2)


if KIND == "scaling":
    SCALING_PROFILE = dict(config.get("profile") or {})
    SCALING_PROFILE.setdefault("elements", max(config["elements"]))
    SCALING_SIZES = {int(label): size for label, size in checked_cases(
        (str(m), {"problem": "contact", "method": "active-set", "subdomains": int(config["subdomains"]),
                  "elements": int(m)}) for m in dict.fromkeys(list(config["elements"]) +
                                                               [SCALING_PROFILE["elements"]])).items()}


# --- kind ngsolve (ngsolve.smk) -------------------------------------------------------------
# One job for the whole study (ddstudies.ngsolve_bench); its settings travel as JSON in params.
import json

#: Config keys handed to ddstudies.ngsolve_bench.
NGSOLVE_KEYS = ("orders", "solvers", "dofs_per_part", "rtol", "maxiter", "parts_sweep", "scaling_study", "cube")


# --- kind unstructured (unstructured.smk) -----------------------------------------------------
# One job per (problem, refinement), running every method of the problem (peers included) in one
# process and taking all the cores given to Snakemake, so that jobs run one at a time.


def unstructured_case_files(wildcards=None):
    return [f"results/{STUDY}/{problem}/r{r}.csv"
            for problem, series in config["problems"].items() for r in series["refine"]]


def unstructured_case(wildcards):
    """The parameters of one job (a params value: a changed parameter reruns the job)."""
    from ddstudies.bench.unstructured import case_methods, parts_for

    series = config["problems"][wildcards.problem]
    refine = int(wildcards.refine)
    try:
        parts = parts_for(series["refine"], series["parts"])[refine]
    except (ValueError, KeyError) as err:
        config_error(f"invalid config: problems: {wildcards.problem}: {err}")
    contact = wildcards.problem == "contact"
    methods = case_methods(series["methods"], refine, series.get("max_refine"))
    case = {"problem": wildcards.problem, "maxh": float(series["maxh"]), "refine": refine, "parts": parts,
            "methods": methods,
            "rtol": float(config.get("contact_rtol", 1e-5) if contact else config.get("rtol", 1e-8)),
            "maxiter": int(config.get("maxiter", 1000)), "seed": int(config.get("seed", 0))}
    # only what the job reads, so that a parameter it does not use reruns nothing: the condition estimates are
    # Poisson's, the direct backend is that of contact's pdas faces (the Poisson direct peers are methods)
    if not contact:
        case["cond"] = bool(config.get("cond", True))
    elif "pdas" in methods:
        case.update(direct=config.get("direct", "mkl-pardiso"), direct_threads=int(config.get("direct_threads", 1)))
    return case


def unstructured_cond_files(wildcards=None):
    """The result files of the condition-number sweeps (config `cond_law`; none without it)."""
    return list(COND_SPECS)


def unstructured_cond_spec(wildcards):
    """The ProblemSpec mapping of one condition-number case (a params value)."""
    return COND_SPECS[f"results/{STUDY}/cond/{wildcards.method}/{wildcards.stem}.h5"]


def unstructured_cond_size(wildcards):
    return COND_SIZES[f"results/{STUDY}/cond/{wildcards.method}/{wildcards.stem}.h5"]


def unstructured_figure_spec(wildcards=None):
    """The ProblemSpec mapping of the contact figure (config `contact_figure`)."""
    fig = config["contact_figure"]
    return {"problem": "contact", "mesh": "unstructured", "maxh": float(fig["maxh"]), "refine": int(fig["refine"]),
            "parts": int(fig["parts"]), "method": fig["method"], "rtol": float(fig["rtol"])}


def unstructured_report_files():
    """The reports of an unstructured study: the timing series, the cond law and the contact figure."""
    files = [f"reports/{STUDY}/{name}" for name in ("unstructured.png", "unstructured.csv", "unstructured.md")]
    if "cond_law" in config:
        files += [f"reports/{STUDY}/{name}" for name in ("cond_law.md", "cond_law.csv", "cond_law.png")]
    if "contact_figure" in config:
        files.append(f"reports/{STUDY}/contact_solution.png")
    return files


if KIND == "unstructured":
    for _problem, _series in config["problems"].items():
        if not isinstance(_series["parts"], int) and len(_series["parts"]) != len(_series["refine"]):
            config_error(f"invalid config: problems: {_problem}: parts: {len(_series['parts'])} values for "
                                f"{len(_series['refine'])} refinements")
    from ddstudies.bench.unstructured import parts_for as _parts_for

    # every job's mesh must fit the machine, as every case of the other kinds (before any job runs)
    checked_cases((f"problems/{_problem}/refine/{_r}",
                   {"problem": _problem, "method": "fetidp" if _problem == "poisson" else "active-set",
                    "mesh": "unstructured", "maxh": float(_series["maxh"]), "refine": int(_r),
                    "parts": _parts_for(_series["refine"], _series["parts"])[_r]})
                  for _problem, _series in config["problems"].items() for _r in _series["refine"])
    COND_SPECS = {}
    if "cond_law" in config:
        from ddstudies.bench import cond_law as studies_cond_law

        _law = config["cond_law"]
        try:
            studies_cond_law.require_points(_law)
            COND_SPECS = {f"results/{STUDY}/cond/{case.method}/{case.stem}.h5": studies_cond_law.case_spec(
                case, rtol=_law["rtol"], maxiter=_law["maxiter"]) for case in studies_cond_law.cond_cases(_law)}
        except ValueError as err:
            config_error(f"invalid config: cond_law: {err}")
    # every case (and the figure) is a valid ProblemSpec that fits the machine, before any job runs
    COND_SIZES = checked_cases(COND_SPECS.items())
    if "contact_figure" in config:
        FIGURE_SIZE = checked_cases([("contact_figure", unstructured_figure_spec())])["contact_figure"]


# --- kind stress (stress.smk) ---------------------------------------------------------------
# The cases are the catalog of ddstudies.stress (tier `tier`); each series job gets its
# cases in `params`, so a changed case reruns its series. Case names are unique.


def _stress_job(case):
    """The job of a case: its series; in the quick tier (a smoke test) its group, for fewer jobs."""
    return case.group if config["tier"] == "quick" else case.series


def stress_series_cases(wildcards):
    """The cases of one job as plain dicts (a params value: a changed case reruns its job)."""
    return [asdict(case) for case in STRESS_CASES if _stress_job(case) == wildcards.series]


#: mem_mb of a stress series job (its largest cases are the catalog's "many subdomains" sizes).
STRESS_MEM_MB = 4000


def stress_runtime(wildcards):
    """runtime (minutes) of a stress series: every case may take its `case_timeout`."""
    n = sum(1 for case in STRESS_CASES if _stress_job(case) == wildcards.series)
    return max(15, int(n * float(config["case_timeout"]) / 60.0) + 5)


if KIND == "stress":
    from ddstudies.stress.catalogue import catalog as stress_catalog

    try:
        STRESS_CASES = list(studies_workflow.unique_labels(
            ((case.name, case) for case in stress_catalog(config["tier"])), "stress cases").values())
    except studies_workflow.ConfigError as err:
        config_error(str(err))
    STRESS_SERIES = list(dict.fromkeys(_stress_job(case) for case in STRESS_CASES))


# --- kind mpi (mpi.smk) ---------------------------------------------------------------------
# One job per number of ranks P, each launched with mpiexec -n P (resources tasks=P, mpi).


MPI_CONTACT_METHOD = "active-set"      # the method of the optional contact case


def mpi_methods():
    """The methods of the study: the Poisson method, then the contact case's when configured."""
    return [config["method"]] + ([MPI_CONTACT_METHOD] if config.get("contact") else [])


def mpi_spec(wildcards):
    """The ddsolve solve flags of the case (a plain dict: a params value)."""
    common = {key: config[key] for key in ("rtol", "maxiter")}
    if wildcards.method == MPI_CONTACT_METHOD:
        return studies_workflow.sorted_keys({"problem": "contact", "method": MPI_CONTACT_METHOD, **config["contact"],
                                             **common})
    return studies_workflow.sorted_keys({key: config[key] for key in ("method", "subdomains", "elements")} | common)


def mpi_case_files(wildcards=None):
    return [f"results/{STUDY}/{method}/P{P}.json" for method in mpi_methods() for P in config["ranks"]]


if KIND == "mpi":     # every case must fit the machine (a P = 1 run holds it all), as the other kinds' cases
    checked_cases((f"{method}", mpi_spec(SimpleNamespace(method=method))) for method in mpi_methods())
    from ddsolve.errors import InputError
    from ddsolve.parallel.run import check_supported
    from ddsolve.spec import ProblemSpec

    for _method in mpi_methods():     # what mpiexec would refuse on every rank (e.g. more ranks than subdomains)
        for _P in config["ranks"]:
            try:
                check_supported(ProblemSpec.from_mapping(mpi_spec(SimpleNamespace(method=_method))), int(_P))
            except InputError as err:
                config_error(f"invalid config: ranks: {_P} for {_method}: {err}")


def mpi_previous_case(wildcards):
    """The case timed just before this one: the cases run one after another, never beside each other
    (two timed runs sharing the cores would measure each other), whatever --cores or the executor allow."""
    files = mpi_case_files()
    index = files.index(f"results/{STUDY}/{wildcards.method}/P{wildcards.P}.json")
    return files[index - 1:index] if index > 0 else []


def targets():
    """The reports of the study (the input of rule all)."""
    if KIND == "mpi":
        return [f"reports/{STUDY}/mpi.csv", f"reports/{STUDY}/mpi.md"]
    if KIND in GRID_KINDS:
        return grid_report_files()
    if KIND == "bench":
        return [f"reports/{STUDY}/work_precision.png", f"reports/{STUDY}/work_precision.csv"]
    if KIND == "scaling":
        return [f"reports/{STUDY}/{name}" for name in ("scaling.png", "scaling.csv", "scaling.md", "profile.txt")]
    if KIND == "ngsolve":
        return [f"reports/{STUDY}/ngsolve.md", f"reports/{STUDY}/ngsolve.png", f"results/{STUDY}/ngsolve.csv"]
    if KIND == "unstructured":
        return unstructured_report_files()
    return [f"reports/{STUDY}/stress.md", f"results/{STUDY}/stress.csv"]


# Integrity of results (docs/studies.md, "Integrity of results"): truncated result files are
# moved aside, and results missing below an existing summary or report are recomputed.
if KIND in GRID_KINDS:
    check_result_files(case_files(), f"results/{STUDY}/summary.csv",
                       [path for path in targets() if "figure_5_2" not in path],
                       manifest=f"results/{STUDY}/summary.sha256")
elif KIND == "bench":
    check_result_files([f"results/{STUDY}/{kind}/reference.h5" for kind in config["problems"]])
    check_result_files(bench_case_files(), f"results/{STUDY}/summary.csv", targets(),
                       manifest=f"results/{STUDY}/summary.sha256")
elif KIND == "scaling":
    check_result_files(scaling_case_files(), f"results/{STUDY}/summary.csv",
                       [path for path in targets() if not path.endswith("profile.txt")],
                       manifest=f"results/{STUDY}/summary.sha256")
elif KIND == "unstructured" and COND_SPECS:
    check_result_files(unstructured_cond_files(), f"results/{STUDY}/cond/summary.csv",
                       [f"reports/{STUDY}/cond_law.{ext}" for ext in ("md", "csv", "png")],
                       manifest=f"results/{STUDY}/cond/summary.sha256")
# the JSON / CSV job results of the mpi, stress and unstructured studies: one deleted is recomputed with
# everything made from it (their contents are checked when read: ddstudies.workflow.read_job_results)
if MAIN_PROCESS and not READ_ONLY and KIND in ("mpi", "stress", "unstructured"):
    _job_results = {"mpi": mpi_case_files, "unstructured": unstructured_case_files,
                    "stress": lambda: expand(f"results/{STUDY}/cases/{{series}}.json", series=STRESS_SERIES)}[KIND]()
    studies_workflow.rebuild_below_missing(_job_results, targets() + ([f"results/{STUDY}/summary.csv"]
                                           if KIND == "unstructured" else []),
                                           log=lambda line: print(line, file=sys.stderr))
