"""The workflow's config: option lists injected from ddsolve.options, explicit kinds, unique job labels."""
from __future__ import annotations

import pytest
import yaml
from conftest import ROOT, copy_workflow
from conftest import run_snakemake as snakemake

from ddsolve import options
from ddstudies.workflow import SCHEMAS, ConfigError, bench_rtols, load_schema, unique_labels, validate

SCHEMA_DIR = ROOT / "workflows" / "schemas"


def test_schema_option_lists_come_from_ddsolve_options():
    schema = load_schema(SCHEMA_DIR / "config.schema.yaml")
    props = schema["properties"]
    assert props["methods"]["items"]["enum"] == list(options.ALL_METHODS)
    assert props["contacts"]["items"]["enum"] == list(options.CONTACTS)
    assert props["scaling"]["enum"] == list(options.SCALINGS)
    assert props["norm"]["enum"] == list(options.NORMS)
    assert props["projection"]["enum"] == list(options.PROJECTIONS)
    assert props["problem"]["enum"] == list(options.METHODS)
    assert "x-options:" not in yaml.safe_dump(schema)
    # no copied list left in the schema file itself
    text = (SCHEMA_DIR / "config.schema.yaml").read_text()
    assert "enum: [feti" not in text and "enum: [full, middle]" not in text and "enum: [l2, M]" not in text


def test_per_kind_methods():
    base = {"kind": "table_4", "study": "s", "problem": "multibody", "contacts": ["full"], "subdomains": [2],
            "elements": [2], "thesis_tables": "t", "tables": {"t": {"method": "hybrid", "title": "T"}},
            "figures": {"f": {"method": "hybrid", "title": "F"}}}
    validate({**base, "methods": ["hybrid"]}, SCHEMA_DIR / "config.schema.yaml")
    with pytest.raises(ConfigError, match="methods/0"):
        validate({**base, "methods": ["bddc"]}, SCHEMA_DIR / "config.schema.yaml")
    with pytest.raises(ConfigError):  # a kind and its problem agree
        validate({**base, "problem": "poisson", "methods": ["hybrid"]}, SCHEMA_DIR / "config.schema.yaml")


@pytest.mark.parametrize("name", ["poisson", "table_4", "table_5_6", "bench", "scaling", "stress", "unstructured"])
def test_every_config_names_its_kind(name):
    config = yaml.safe_load((ROOT / "config" / f"{name}.yaml").read_text())
    validate(config, SCHEMA_DIR / f"{SCHEMAS[config['kind']]}.schema.yaml")
    assert config["study"] == name


def test_stress_settings_in_config():
    config = validate(yaml.safe_load((ROOT / "config" / "stress.yaml").read_text()),
                      SCHEMA_DIR / "stress.schema.yaml")
    assert config["tier"] == "study" and config["case_timeout"] == 240
    with pytest.raises(ConfigError, match="tier"):
        validate({**config, "tier": "huge"}, SCHEMA_DIR / "stress.schema.yaml")


def test_bench_labels_unique_by_construction():
    assert list(bench_rtols([1e-2, 1e-6])) == ["rtol1e-02", "rtol1e-06"]
    with pytest.raises(ConfigError, match=r"1e-06 and 1.4e-06 both have the label 'rtol1e-06'"):
        bench_rtols([1e-6, 1.4e-6])
    with pytest.raises(ConfigError, match="'a'"):
        unique_labels([("a", 1), ("a", 2)], "things")


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return copy_workflow(tmp_path_factory.mktemp("workflow_config"))


def test_workflow_refuses_colliding_bench_labels(workdir):
    (workdir / "clash.yaml").write_text("rtols: [1.0e-6, 1.4e-6]\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/bench.yaml", "clash.yaml", check=False)
    assert proc.returncode != 0
    assert "rtols: 1e-06 and 1.4e-06 both have the label 'rtol1e-06'" in proc.stdout + proc.stderr


@pytest.mark.parametrize("override, message", [
    ("problems: {poisson: {load_cells: 256}}", "problems: poisson: load_cells: 256 must divide the 128 elements"),
    ("problems: {poisson: {load_cells: 3}}", "problems: poisson: load_cells: 3 must divide the 128 elements"),
    ("problems: {multibody: {spec: {f: 1}}}", "problems: multibody: load_cells: 8 applies to a random"),
])
def test_workflow_refuses_a_load_grid_the_mesh_does_not_resolve(workdir, override, message):
    (workdir / "cells.yaml").write_text(override + "\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/bench.yaml", "cells.yaml", check=False)
    assert proc.returncode != 0 and message in proc.stdout + proc.stderr


def test_load_cells_that_tile_the_grid_are_accepted():
    from ddsolve.spec import ProblemSpec
    from ddstudies.bench.problems import bench_scene, check_load_cells

    spec = ProblemSpec(problem="poisson", method="fetidp", subdomains=2, elements=4, f="random:0")
    check_load_cells(spec, 8)
    check_load_cells(spec, 2)
    check_load_cells(spec, None)
    with pytest.raises(ValueError, match="load_cells: 16 must divide the 8 elements per side"):
        bench_scene(spec, 16)


def test_list_items_from_the_command_line_are_read_as_numbers():
    # snakemake --config subdomains=[2,3] passes ['2', '3'] (YAML's base loader)
    data = {"kind": "bench", "rtols": ["1e-2", "1.0e-6"], "problems": {"poisson": {"spec": {}, "methods": ["bddc"],
                                                                                   "load_cells": "4"}}}
    validate(data, SCHEMA_DIR / "bench.schema.yaml")
    assert data["rtols"] == [1e-2, 1e-6] and data["problems"]["poisson"]["load_cells"] == 4
    with pytest.raises(ConfigError, match="rtols/1: 'x' is not of type 'number'"):
        validate({"kind": "bench", "rtols": ["1e-2", "x"], "problems": {"poisson": {"methods": ["bddc"]}}},
                 SCHEMA_DIR / "bench.schema.yaml")
    data = {"kind": "grid", "study": "2024", "methods": ["bddc"], "subdomains": ["2", "3"], "elements": ["4"]}
    validate(data, SCHEMA_DIR / "config.schema.yaml")
    assert data["subdomains"] == [2, 3] and data["study"] == "2024"      # a string stays where one is wanted


def test_list_items_inside_one_of_are_read_as_numbers():
    """bodies and subdomains of a sweep are an integer or a list of them (oneOf): --config 'bodies=[2,3]'
    was refused ("'2' is not of type 'integer'", a review)."""
    import yaml

    data = yaml.safe_load((ROOT / "config" / "table_4.yaml").read_text())
    data["sweeps"] = [{"bodies": ["2", "3"], "subdomains": "2", "elements": "2"}]
    validate(data, SCHEMA_DIR / "config.schema.yaml")
    assert data["sweeps"] == [{"bodies": [2, 3], "subdomains": 2, "elements": 2}]


def test_params_do_not_depend_on_the_order_of_keys():
    """Snakemake's params rerun-trigger compares reprs: a config saved with sorted keys reran every case."""
    from ddstudies.workflow import sorted_keys

    a = {"subdomains": 2, "elements": 4, "f": {"b": 1, "a": [{"y": 1, "x": 2}]}}
    b = {"f": {"a": [{"x": 2, "y": 1}], "b": 1}, "elements": 4, "subdomains": 2}
    assert repr(sorted_keys(a)) == repr(sorted_keys(b)) and sorted_keys(a) == a
    assert sorted_keys([3, 1]) == [3, 1]                      # lists keep their order


def test_a_config_error_is_one_line_with_status_2(workdir):
    """As the command line's bad input: one line, exit status 2 (it was a WorkflowError with Snakemake's
    header and 3-4 lines of call stack; a review); the grid keys next to sweeps are refused (ignored before),
    also from a study entry of the reproduction, whose name the line gives."""
    (workdir / "both.yaml").write_text("kind: grid\nstudy: b\nmethods: [bddc]\nsubdomains: [7]\n"
                                       "sweeps: [{subdomains: [2], elements: [2]}]\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "both.yaml", check=False)
    errors = [line for line in proc.stderr.splitlines() if "error" in line.lower()]
    assert proc.returncode == 2 and errors == [
        "ddsolve: error: invalid config (config.schema.yaml): subdomains: not allowed here (not with sweeps (they "
        "replace the grid; give it in a sweep))"], proc.stderr
    assert "Traceback" not in proc.stderr and 'File "' not in proc.stderr
    (workdir / "studies.yaml").write_text("studies: [{name: mine, configfile: both.yaml}]\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "studies.yaml", check=False)
    assert proc.returncode == 2 and "ddsolve: error: studies: mine (both.yaml): invalid config" in proc.stderr


def test_more_config_errors_are_one_line(workdir):
    """A studies entry whose file is not YAML or not a mapping (tracebacks), "nan" written as a string
    (planned its jobs), a top-level bodies every sweep overrides (ignored): one line, exit status 2."""
    (workdir / "broken.yaml").write_text("kind: grid\nstudy: x\nmethods: [feti\n")
    (workdir / "list.yaml").write_text("- 1\n- 2\n")
    cases = [(["--configfile", "s1.yaml"], "studies: p: configfile broken.yaml is not valid YAML"),
             (["--configfile", "s2.yaml"], "studies: p: configfile list.yaml must hold a YAML mapping"),
             (["--configfile", "config/bench.yaml", "--config", "rtols=[1e-2,nan]"],
              "invalid config: rtols/1: must be a finite number, got nan"),
             (["--configfile", "config/table_4.yaml", "--config", "bodies=5"],
              "invalid config: bodies: every sweep gives its own bodies"),
             (["--configfile", "nokind.yaml"], "invalid config: kind: a single-study config names its kind and "
                                                "study (e.g. kind: grid, study: mine); got elements, methods")]
    (workdir / "nokind.yaml").write_text("methods: [bddc]\nsubdomains: [2]\nelements: [2]\n")
    cases.append((["--configfile", "mm.yaml"], "ddsolve: error: invalid config: max_memory: must be a finite number"))
    (workdir / "mm.yaml").write_text("max_memory: .nan\nstudies: [{name: p, configfile: config/poisson.yaml}]\n")
    (workdir / "s1.yaml").write_text("studies: [{name: p, configfile: broken.yaml}]\n")
    (workdir / "s2.yaml").write_text("studies: [{name: p, configfile: list.yaml}]\n")
    for args, message in cases:
        proc = snakemake(workdir, "-n", "--cores", "1", *args, check=False)
        errors = [line for line in proc.stderr.splitlines() if "error" in line.lower()]
        assert proc.returncode == 2 and len(errors) == 1 and message in errors[0], (args, proc.stderr)


def test_workflow_needs_an_explicit_kind(workdir):
    # a study named stress* is not a stress study: only `kind` says what a study is
    (workdir / "nokind.yaml").write_text("study: stress_like\nmethods: [bddc]\nsubdomains: [2]\nelements: [2]\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "nokind.yaml", check=False)
    assert proc.returncode != 0 and "kind: None is not one of" in proc.stdout + proc.stderr
    (workdir / "grid.yaml").write_text("kind: grid\nstudy: stress_like\nmethods: [bddc]\nsubdomains: [2]\n"
                                       "elements: [2]\n")
    out = snakemake(workdir, "-n", "--cores", "1", "--configfile", "grid.yaml")
    text = out.stdout + out.stderr
    assert "solve_case" in text and "stress_series" not in text


def test_lint_is_clean(workdir):
    for args in ((), ("--configfile", "config/quick.yaml")):
        proc = snakemake(workdir, "--lint", *args, check=False)
        assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.parametrize("extra", ["", "rho: checkerboard:10\n", "scaling: multiplicity\n", "gamma: 2\n"])
def test_evidence_reports_only_for_the_thesis_coefficient(workdir, extra):
    """The contact work-precision report runs its own solves with rho = 1, rho-scaling, gamma = 1: a study with
    another coefficient or scaling does not make it (its numbers were rho = 1's under the study's name)."""
    (workdir / "contact.yaml").write_text(
        "kind: contact\nstudy: evidence\nproblem: contact\nmethods: [active-set, smalbe]\nsubdomains: [2]\n"
        "elements: [4]\nrtol: 1.0e-6\ncond: false\ncheck: false\nthesis_tables: config/thesis_tables\n"
        "tables:\n  table_5_1: {method: active-set}\n  table_6_1: {method: smalbe}\n"
        "figure_5_2: {method: active-set, subdomains: 2, elements: 4}\n" + extra)
    text = "".join(snakemake(workdir, "-n", "--cores", "1", "--configfile", "contact.yaml").stdout)
    assert "table_5_1" in text
    assert ("contact_work_precision" in text) == (extra == "")


@pytest.mark.parametrize("extra, made", [("", True), ("norm: M\n", False), ("projection: lumped\n", False)])
def test_table_4_evidence_reports_only_for_the_thesis_rules(workdir, extra, made):
    """The Table 4.2 evidence report solves with norm l2 and the orthogonal projection: a study with norm: M got
    it under its own name, with counts of another norm than its table's (a review)."""
    (workdir / "t4.yaml").write_text("methods: [hybrid]\nsweeps: [{bodies: 2, subdomains: 2, elements: 2}]\n"
                                     + extra)
    text = "".join(snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/table_4.yaml", "t4.yaml").stdout)
    assert "table_4_2.md" in text
    assert ("table_4_2_optimal" in text) == made


def test_figure_fit_model_is_checked():
    """An unknown fit model was accepted and failed the figure job (ValueError) after every solve had run."""
    data = yaml.safe_load((ROOT / "config" / "table_4.yaml").read_text())
    name = next(n for n, fig in data["figures"].items() if "model" in fig)
    data["figures"][name]["model"] = "cubic"
    with pytest.raises(ConfigError, match=rf"figures/{name}/model: 'cubic' is not one of \['linear'"):
        validate(data, SCHEMA_DIR / "config.schema.yaml")


@pytest.mark.parametrize("config", [
    "kind: contact\nstudy: nocond\nproblem: contact\nmethods: [active-set, smalbe]\nsubdomains: [2]\nelements: [4]\n"
    "check: false\nthesis_tables: config/thesis_tables\ntables:\n  table_5_1: {method: active-set}\n"
    "  table_6_1: {method: smalbe}\nfigure_5_2: {method: active-set, subdomains: 2, elements: 4}\n",
    "kind: grid\nstudy: nocond\nmethods: [fetidp, direct]\nsubdomains: [2]\nelements: [2]\n",
])
def test_cond_default_applies_to_methods_with_an_estimate(workdir, config):
    """Leaving cond out (schema default true) refused every contact method and direct ('cond: true does not
    apply'): a study's cond now asks for the estimates of the methods that have them."""
    (workdir / "nocond.yaml").write_text(config)
    out = snakemake(workdir, "-n", "--cores", "1", "--configfile", "nocond.yaml")
    assert "solve_case" in out.stdout + out.stderr


@pytest.mark.parametrize(("tables", "message"), [
    ({"table_5_1": {"method": "smalbe"}}, r"tables/table_5_1/method: 'active-set' was expected"),
    ({"table_6_1": {"method": "active-set"}}, r"tables/table_6_1/method: 'smalbe' was expected"),
    ({"table_9": {"method": "smalbe"}}, r"tables: Additional properties are not allowed \('table_9'"),
])
def test_contact_tables_are_the_thesis_tables(tables, message):
    """Table 5.1 is the active set method's and Table 6.1 SMALBE's: a table_5_1 with method smalbe was accepted
    and rendered as an empty table (its method key was not read), an unknown table failed a job later."""
    data = yaml.safe_load((ROOT / "config" / "table_5_6.yaml").read_text())
    data["tables"] = tables
    with pytest.raises(ConfigError, match=message):
        validate(data, SCHEMA_DIR / "config.schema.yaml")


def test_unstructured_methods_per_problem():
    """Each problem's series takes only its own methods (poisson: active-set was accepted and failed the job
    with a ValueError); the lists are those of ddstudies.bench.unstructured.METHODS."""
    from ddstudies.bench.unstructured import METHODS

    schema = load_schema(SCHEMA_DIR / "unstructured.schema.yaml")
    for problem, methods in METHODS.items():
        assert schema["properties"]["problems"]["properties"][problem]["properties"]["methods"]["items"]["enum"] \
            == list(methods)
    data = {"kind": "unstructured", "problems": {"poisson": {"maxh": 0.2, "refine": [0], "parts": 2,
                                                             "methods": ["fetidp", "active-set"]}}}
    with pytest.raises(ConfigError, match=r"problems/poisson/methods/1: 'active-set' is not one of"):
        validate(data, SCHEMA_DIR / "unstructured.schema.yaml")


def test_cases_are_checked_as_the_solver_checks_them():
    """A contact case with one subdomain per body side passed the planning and failed its job with a traceback;
    check_cases refuses what `ddsolve solve` refuses before building a scene (ddsolve.prepared.check_decomposition)."""
    from ddstudies.workflow import check_cases

    case = {"problem": "contact", "method": "active-set", "bodies": 2, "subdomains": 1, "elements": 4}
    with pytest.raises(ConfigError, match=r"^invalid config: case c1: subdomains: method 'active-set' needs at least 2"):
        check_cases([("c1", case)])
    assert set(check_cases([("c2", {**case, "subdomains": 2})])) == {"c2"}


@pytest.mark.parametrize(("change", "message"), [
    ({"tables": {"table_9": {"method": "feti-feti", "title": "T9"}}},
     "no transcription 'table_9' in 'config/thesis_tables' (it has ['table_4_1'"),
    ({"thesis_tables": "config/nothere"}, "no transcription 'table_4_1' in 'config/nothere' (no such folder)"),
    # an existing transcription of another chapter failed the report job (KeyError) after the solves
    ({"tables": {"table_4_1": {"method": "feti-feti", "title": "T", "thesis": "table_5_1"}}},
     "ddsolve: error: invalid config: thesis: the transcription 'table_5_1' (config/thesis_tables/table_5_1.csv) "
     "has no column inv_Hb, Hb_over_Hs, Hs_over_h"),
    ({"figures": {"figure_4_2": {"method": "feti-feti", "x": "subdomains", "y": "cond", "title": "F",
                               "thesis": "table_6_1"}}},
     "the transcription 'table_6_1' (config/thesis_tables/table_6_1.csv) has no column inv_Hb"),
])
def test_missing_thesis_transcriptions_are_config_errors(workdir, change, message):
    """A table without a thesis transcription, or a missing folder, ended in Snakemake's MissingInputException."""
    data = yaml.safe_load((ROOT / "config" / "table_4.yaml").read_text())
    for key, value in change.items():
        data[key] = {**data[key], **value} if isinstance(value, dict) else value
    (workdir / "t4.yaml").write_text(yaml.safe_dump(data))
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "t4.yaml", check=False)
    assert proc.returncode == 2 and message in proc.stdout + proc.stderr


@pytest.mark.parametrize(("problems", "message"), [
    ({"heat": {"spec": {"subdomains": 2, "elements": 4}, "methods": ["fetidp"]}},
     r"problems: 'heat' is not one of \['poisson', 'multibody', 'contact'\]"),
    ({"poisson": {"spec": {"subdomains": 2, "elements": 4}, "methods": [], "peers": []}},
     r"problems/poisson/methods: must not be empty"),
])
def test_bench_problems_are_checked(problems, message):
    """An unknown problem was a KeyError in the planning (no key path); no methods and no peers an empty report."""
    data = {"kind": "bench", "rtols": [1e-2], "problems": problems}
    with pytest.raises(ConfigError, match=message):
        validate(data, SCHEMA_DIR / "bench.schema.yaml")


@pytest.mark.parametrize("override, message", [
    ("problems: {poisson: {methods: [fetdp]}}", "invalid config: problems: poisson: methods: unknown benchmark method"),
    ("problems: {poisson: {peers: [pdas]}}", "invalid config: problems: poisson: peers: method 'pdas' does not solve"),
    ("direct: cholmod", "invalid config: direct: backend 'cholmod' is not installed here"),
])
def test_bench_methods_and_backends_are_checked_while_planning(workdir, override, message):
    """Were a KeyError traceback without a key path, and a failure of the first job (sixth review)."""
    from ddstudies.bench.peers import available_direct_solvers

    if "cholmod" in override and "cholmod" in available_direct_solvers():
        pytest.skip("cholmod is installed here")
    (workdir / "bad_bench.yaml").write_text(override + "\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/bench.yaml", "bad_bench.yaml", check=False)
    assert proc.returncode != 0 and message in proc.stdout + proc.stderr


def test_a_bad_study_entry_is_named_and_max_memory_reaches_the_studies(workdir):
    (workdir / "which.yaml").write_text(
        "studies:\n  - {name: p, configfile: config/poisson.yaml, set: {study: my_p, subdomains: [2], elements: [2]}}\n"
        "  - {name: c, configfile: config/table_5_6.yaml, set: {study: my_c, rtol: 2.0}}\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "which.yaml", check=False)
    assert proc.returncode != 0
    assert "studies: c (config/table_5_6.yaml): invalid config (config.schema.yaml): rtol:" in proc.stdout + proc.stderr
    (workdir / "tight.yaml").write_text(
        "max_memory: 1M\nstudies:\n  - {name: p, configfile: config/poisson.yaml, set: {study: my_p}}\n")
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "tight.yaml", check=False)
    assert proc.returncode != 0 and "more than max_memory (1 MiB)" in proc.stdout + proc.stderr    # was 'unexpected key'


@pytest.mark.parametrize("config, message", [
    ("kind: unstructured\nstudy: u\nproblems: {poisson: {maxh: 1.0e-4, refine: [0], parts: 4, "
     "methods: [fetidp]}}\n", "invalid config: case problems/poisson/refine/0: needs about"),
    ("kind: mpi\nstudy: m\nmethod: fetidp\nsubdomains: 20000\nelements: 2000\nranks: [1, 2]\n",
     "invalid config: case fetidp: needs about"),
    ("kind: mpi\nstudy: m\nmethod: fetidp\nsubdomains: 2\nelements: 4\nranks: [1, 64]\n",
     "invalid config: ranks: 64 for fetidp: subdomains: 4 subdomains for 64 ranks"),
])
def test_unstructured_and_mpi_cases_are_sized_while_planning(workdir, config, message):
    """These passed planning and failed (or took the machine's memory) in their jobs (sixth review)."""
    (workdir / "sized.yaml").write_text(config)
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "sized.yaml", check=False)
    assert proc.returncode != 0 and message in proc.stdout + proc.stderr


def test_json_and_csv_job_results_are_checked_and_moved_aside(tmp_path):
    """A truncated JSON gave a JSONDecodeError traceback on every rerun, a CSV cut to its header dropped
    its rows from the report without a word (a review); both are named and moved aside now."""
    from ddstudies.aggregate import CorruptResultsError
    from ddstudies.workflow import read_job_results

    good_json, good_csv = tmp_path / "P1.json", tmp_path / "r0.csv"
    good_json.write_text('{"problem": "poisson", "iterations": 13}')
    good_csv.write_text("ndof,iterations\n81,7\n")
    json_value, csv_value = read_job_results([good_json, good_csv])
    assert json_value == {"problem": "poisson", "iterations": 13} and csv_value["iterations"].tolist() == [7]
    cut_json, header_csv, empty = tmp_path / "P2.json", tmp_path / "r1.csv", tmp_path / "jumps.json"
    cut_json.write_text('{"problem": "poi')
    header_csv.write_text("ndof,iterations\n")
    empty.write_text("[]")
    with pytest.raises(CorruptResultsError, match=r"P2.json: corrupt result file: JSONDecodeError.*\(and 2 more: "
                                                  r".*r1.csv, .*jumps.json\); moved aside") as err:
        read_job_results([good_json, cut_json, header_csv, empty])
    assert len(err.value.paths) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["P1.json", "P2.json.corrupt", "jumps.json.corrupt",
                                                          "r0.csv", "r1.csv.corrupt"]


def test_a_deleted_json_or_csv_result_removes_what_was_made_from_it(tmp_path):
    """Snakemake does not recreate a missing intermediate file under up-to-date reports (a review: a deleted
    P2.json or r1.csv stayed missing); the reports are removed, so the run rebuilds the result and them."""
    from ddstudies.workflow import rebuild_below_missing

    results = [tmp_path / "P1.json", tmp_path / "P2.json"]
    reports = [tmp_path / "mpi.md", tmp_path / "mpi.csv"]
    for path in results + reports:
        path.write_text("{}")
    lines = []
    assert rebuild_below_missing(results, reports, log=lines.append) == []       # all there: nothing removed
    results[1].unlink()
    assert rebuild_below_missing(results, reports, log=lines.append) == [str(p) for p in reports]
    assert not any(p.exists() for p in reports) and results[0].exists()
    assert lines == [f"{results[1]} is missing: removed {reports[0]}, {reports[1]} to rebuild them"]
    # the HTML copy of a table for the report goes with it (a stale table.html outlived its table: a review)
    results[1].write_text("{}")
    twin = tmp_path / "mpi.html"
    for path in reports + [twin]:
        path.write_text("{}")
    results[1].unlink()
    assert rebuild_below_missing(results, reports) == [str(reports[0]), str(twin), str(reports[1])]
    assert not twin.exists()


@pytest.mark.parametrize("change, expected", [
    ({"subdomains": None}, r"\(top level\): needs 'subdomains' and 'elements' or 'sweeps'$"),
    ({"contacts": ["full"]}, r"contacts: not allowed here \(only for the multibody problem\)$"),
    ({"methods": []}, r"methods: must not be empty$"),
])
def test_schema_errors_name_the_key(change, expected):
    """jsonschema's messages of anyOf, not and minItems quoted the whole config, cut off, and never named the
    missing key (a review)."""
    import yaml

    data = {**yaml.safe_load((ROOT / "config" / "default.yaml").read_text()),
            **yaml.safe_load((ROOT / "config" / "poisson.yaml").read_text())}
    data.pop("studies")                           # the reproduction's list: one study here
    for key, value in change.items():
        if value is None:
            data.pop(key)
        else:
            data[key] = value
    with pytest.raises(ConfigError, match=expected):
        validate(data, SCHEMA_DIR / "config.schema.yaml")


def test_figure_5_2_of_a_one_preset_study_is_that_preset(workdir):
    """A study of `presets: [thesis]` drew Figure 5.2 with the default rules (a review, 2026-11-28), although
    docs/studies.md says a one-preset study's figures show that preset."""
    presets, study = "[thesis]", "fig52"
    (workdir / f"{study}.yaml").write_text(
        f"kind: contact\nstudy: {study}\nproblem: contact\nmethods: [active-set]\nsubdomains: [2]\nelements: [4]\n"
        f"presets: {presets}\nf: dostal\ncond: false\ncheck: false\nthesis_tables: config/thesis_tables\n"
        "tables:\n  table_5_1: {method: active-set}\nfigure_5_2: {method: active-set, subdomains: 2, elements: 4}\n")
    snakemake(workdir, f"reports/{study}/figure_5_2_surface.png", "--cores", "1", "--configfile", f"{study}.yaml")
    log = (workdir / "logs" / study / "figure_5_2.log").read_text()
    spec_line = next(line for line in log.splitlines() if line.startswith("spec:"))
    assert "'preset': 'thesis'" in spec_line
