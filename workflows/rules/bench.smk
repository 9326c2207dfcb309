# Work-precision benchmark (config/bench.yaml):
#   snakemake --cores 2 --configfile config/bench.yaml
# All its settings live under the config key `bench`. This file is included
# before the study config is validated: it takes `bench` out of the config (so
# the study schema never sees it), validates it against
# workflows/schemas/bench.schema.yaml and, only then, defines its rules;
# `bench_targets()` is then part of rule all (workflows/rules/study.smk).
# Without a `bench` key it defines nothing. (`snakemake bench ...` names the
# target alone.)
#
# Jobs: per problem kind, one reference (direct solves of the problem and of
# its 2x refinement), then one job per (method, rtol) and per peer (the direct
# peer once, pyamg per rtol); then a summary CSV and the plot.
#   results/<study>/<kind>/reference.h5
#   results/<study>/<kind>/<solver>/<tol>.h5      tol = rtol1e-06, ... or "exact"
#   results/<study>/summary.csv                   all collected case files
#   reports/<study>/work_precision.csv, .png      summary table and plot
BENCH = config.pop("bench", None)

if BENCH is not None:
    validate_config(BENCH, "bench", key="config key bench")

    import re as _bench_re
    import sys as _bench_sys

    if workflow.basedir not in _bench_sys.path:     # the repository's ddsolve, also without installing it
        _bench_sys.path.insert(0, workflow.basedir)
    from ddsolve.bench.methods import get_method as _bench_get_method

    BENCH_STUDY = BENCH["study"]

    def _bench_tol(rtol):
        return f"rtol{rtol:.0e}"

    BENCH_RTOLS = {_bench_tol(float(r)): float(r) for r in BENCH["rtols"]}

    def _bench_cases():
        """(kind, solver, tol) of every case, in config order."""
        cases = []
        for kind, prob in BENCH["problems"].items():
            for name in list(prob.get("methods", [])) + list(prob.get("peers", [])):
                if _bench_get_method(name, kind).iterative:
                    cases += [(kind, name, tol) for tol in BENCH_RTOLS]
                else:
                    cases.append((kind, name, "exact"))
        return cases

    BENCH_CASES = _bench_cases()

    def bench_spec(wildcards):
        """ProblemSpec mapping of a problem kind (plain dict: a params value)."""
        prob = BENCH["problems"][wildcards.kind]
        return {**prob["spec"], "problem": wildcards.kind, "maxiter": BENCH["maxiter"]}

    def bench_options(wildcards=None):
        return {"maxiter": BENCH["maxiter"], "threads": BENCH["threads"], "direct": BENCH["direct"],
                "repeats": BENCH["repeats"]}

    def bench_case_files(wildcards=None):
        return [f"results/{BENCH_STUDY}/{kind}/{solver}/{tol}.h5" for kind, solver, tol in BENCH_CASES]

    def bench_targets():
        """The benchmark's reports (part of rule all)."""
        return [f"reports/{BENCH_STUDY}/work_precision.png", f"reports/{BENCH_STUDY}/work_precision.csv"]

    rule bench:
        input:
            bench_targets(),

    rule bench_reference:
        output:
            f"results/{BENCH_STUDY}/{{kind}}/reference.h5",
        wildcard_constraints:
            kind="|".join(_bench_re.escape(k) for k in BENCH["problems"]),
        params:
            spec=bench_spec,
            load_cells=lambda wc: BENCH["problems"][wc.kind].get("load_cells"),
        log:
            f"logs/{BENCH_STUDY}/{{kind}}/reference.log",
        threads: BENCH["threads"]
        script:
            "../scripts/bench_reference.py"

    rule bench_case:
        input:
            reference=f"results/{BENCH_STUDY}/{{kind}}/reference.h5",
        output:
            f"results/{BENCH_STUDY}/{{kind}}/{{solver}}/{{tol}}.h5",
        wildcard_constraints:
            kind="|".join(_bench_re.escape(k) for k in BENCH["problems"]),
            solver=r"[A-Za-z0-9_.+-]+",
            tol="exact|" + "|".join(_bench_re.escape(t) for t in BENCH_RTOLS),
        params:
            spec=bench_spec,
            load_cells=lambda wc: BENCH["problems"][wc.kind].get("load_cells"),
            rtol=lambda wc: BENCH_RTOLS.get(wc.tol),
            options=bench_options,
        log:
            f"logs/{BENCH_STUDY}/{{kind}}/{{solver}}/{{tol}}.log",
        threads: BENCH["threads"]
        script:
            "../scripts/bench_case.py"

    rule bench_summary:
        input:
            bench_case_files(),
        output:
            summary=f"results/{BENCH_STUDY}/summary.csv",
            table=report(f"reports/{BENCH_STUDY}/work_precision.csv", caption="../report/bench_table.rst",
                         category="Work-precision benchmark"),
        log:
            f"logs/{BENCH_STUDY}/summary.log",
        script:
            "../scripts/bench_summary.py"

    rule bench_plot:
        input:
            f"reports/{BENCH_STUDY}/work_precision.csv",
        output:
            report(f"reports/{BENCH_STUDY}/work_precision.png", caption="../report/bench_plot.rst",
                   category="Work-precision benchmark"),
        params:
            time=BENCH["plot_time"],
        log:
            f"logs/{BENCH_STUDY}/plot.log",
        script:
            "../scripts/bench_plot.py"
