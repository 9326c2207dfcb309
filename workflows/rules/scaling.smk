# Scaling study of the contact solvers (config/scaling.yaml):
#   snakemake --cores 2 --configfile config/scaling.yaml
# All its settings live under the config key `contact_scaling` (`scaling` is
# the studies' interface scaling). Like bench.smk, this file is included before
# the Snakefile validates the study config: it takes `contact_scaling` out of
# the config, validates it against workflows/schemas/scaling.schema.yaml and
# only then defines its rules and
# makes `scaling` the default target (unless a `bench` config is also given;
# then name the target: `snakemake scaling ...`). Without a `contact_scaling`
# key it defines nothing.
#
# Jobs: one per (method, H/h), each taking all the cores given to Snakemake so
# that cases run one at a time (BLAS is still limited to 1 thread inside, the
# PARDISO threads are `direct_threads`); then the summary, the plot and a
# cProfile of one active-set solve.
#   results/<study>/<method>/N<N>_m<m>.h5     one case (ddsolve.io.hdf5 layout)
#   results/<study>/summary.csv               all case files
#   reports/<study>/scaling.csv, scaling.md   table, exponent fits, targets
#   reports/<study>/scaling.png               time against dofs
#   reports/<study>/profile.txt               cProfile top functions
SCALING = config.pop("contact_scaling", None)

if SCALING is not None:
    validate(SCALING, "../schemas/scaling.schema.yaml")

    SCALING_STUDY = SCALING.get("study", "scaling")
    SCALING_N = int(SCALING["subdomains"])
    SCALING_PROFILE = dict(SCALING.get("profile") or {})
    SCALING_PROFILE.setdefault("elements", max(SCALING["elements"]))

    def scaling_case_files(wildcards=None):
        return [f"results/{SCALING_STUDY}/{method}/N{SCALING_N}_m{m}.h5"
                for method in SCALING["methods"] for m in SCALING["elements"]]

    def scaling_options(wildcards=None):
        return {key: SCALING.get(key, default) for key, default in
                (("rtol", 1e-5), ("maxiter", 1000), ("direct", "mkl-pardiso"), ("direct_threads", 1),
                 ("repeats", 1), ("repeat_budget", 30.0))}

    rule scaling:
        input:
            f"reports/{SCALING_STUDY}/scaling.png",
            f"reports/{SCALING_STUDY}/scaling.csv",
            f"reports/{SCALING_STUDY}/scaling.md",
            f"reports/{SCALING_STUDY}/profile.txt",

    rule scaling_case:
        output:
            f"results/{SCALING_STUDY}/{{method}}/N{{N}}_m{{m}}.h5",
        wildcard_constraints:
            method="|".join(SCALING["methods"]),
            N=r"\d+",
            m=r"\d+",
        params:
            options=scaling_options,
        log:
            f"logs/{SCALING_STUDY}/{{method}}/N{{N}}_m{{m}}.log",
        threads: workflow.cores
        script:
            "../scripts/scaling_case.py"

    rule scaling_summary:
        input:
            scaling_case_files(),
        output:
            summary=f"results/{SCALING_STUDY}/summary.csv",
            table=f"reports/{SCALING_STUDY}/scaling.csv",
            markdown=f"reports/{SCALING_STUDY}/scaling.md",
        params:
            targets=SCALING.get("targets", {}),
        log:
            f"logs/{SCALING_STUDY}/summary.log",
        script:
            "../scripts/scaling_summary.py"

    rule scaling_plot:
        input:
            f"results/{SCALING_STUDY}/summary.csv",
        output:
            f"reports/{SCALING_STUDY}/scaling.png",
        log:
            f"logs/{SCALING_STUDY}/plot.log",
        script:
            "../scripts/scaling_plot.py"

    rule scaling_profile:
        input:
            # after the timed cases, so that it does not run beside one of them
            scaling_case_files(),
        output:
            text=f"reports/{SCALING_STUDY}/profile.txt",
            stats=f"results/{SCALING_STUDY}/profile.prof",
        params:
            subdomains=SCALING_N,
            elements=int(SCALING_PROFILE["elements"]),
            method=SCALING_PROFILE.get("method", "active-set"),
            top=int(SCALING_PROFILE.get("top", 30)),
            options=scaling_options,
        log:
            f"logs/{SCALING_STUDY}/profile.log",
        threads: workflow.cores
        script:
            "../scripts/scaling_profile.py"

    if BENCH is None:
        # as in bench.smk: keep `scaling` the default target through the later includes
        _scaling_include = workflow.include

        def _include_keeping_scaling_default(*args, **kwargs):
            out = _scaling_include(*args, **kwargs)
            workflow.default_target = "scaling"
            return out

        workflow.include = _include_keeping_scaling_default
