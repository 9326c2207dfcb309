# Scaling study of the contact solvers (config/scaling.yaml):
#   snakemake --cores 2 --configfile config/scaling.yaml
# All its settings live under the config key `contact_scaling` (`scaling` is
# the studies' interface scaling). Like bench.smk, this file is included before
# the Snakefile validates the study config: it takes `contact_scaling` out of
# the config, validates it against workflows/schemas/scaling.schema.yaml and
# only then defines its rules; `scaling_targets()` is then part of rule all
# (workflows/rules/study.smk; `snakemake scaling ...` names the target alone).
# Without a `contact_scaling` key it defines nothing.
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
    validate_config(SCALING, "scaling", key="config key contact_scaling")

    SCALING_STUDY = SCALING.get("study", "scaling")
    SCALING_N = int(SCALING["subdomains"])
    SCALING_PROFILE = dict(SCALING.get("profile") or {})
    SCALING_PROFILE.setdefault("elements", max(SCALING["elements"]))

    def scaling_threads(wildcards):
        """All the cores given to Snakemake, so that the timed cases run one at a time
        (1 where no --cores is given, as for --report)."""
        try:
            return workflow.cores
        except WorkflowError:
            return 1

    def scaling_case_files(wildcards=None):
        return [f"results/{SCALING_STUDY}/{method}/N{SCALING_N}_m{m}.h5"
                for method in SCALING["methods"] for m in SCALING["elements"]]

    def scaling_options(wildcards=None):
        return {key: SCALING.get(key, default) for key, default in
                (("rtol", 1e-5), ("maxiter", 1000), ("direct", "mkl-pardiso"), ("direct_threads", 1),
                 ("repeats", 1), ("repeat_budget", 30.0))}

    def scaling_targets():
        """The scaling study's reports (part of rule all)."""
        return [f"reports/{SCALING_STUDY}/{name}" for name in ("scaling.png", "scaling.csv", "scaling.md",
                                                              "profile.txt")]

    rule scaling:
        input:
            scaling_targets(),

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
        threads: scaling_threads
        script:
            "../scripts/scaling_case.py"

    rule scaling_summary:
        input:
            scaling_case_files(),
        output:
            summary=f"results/{SCALING_STUDY}/summary.csv",
            table=f"reports/{SCALING_STUDY}/scaling.csv",
            markdown=report(f"reports/{SCALING_STUDY}/scaling.md", caption="../report/scaling_table.rst",
                            category="Contact scaling"),
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
            report(f"reports/{SCALING_STUDY}/scaling.png", caption="../report/scaling_plot.rst",
                   category="Contact scaling"),
        log:
            f"logs/{SCALING_STUDY}/plot.log",
        script:
            "../scripts/scaling_plot.py"

    rule scaling_profile:
        input:
            # after the timed cases, so that it does not run beside one of them
            scaling_case_files(),
        output:
            text=report(f"reports/{SCALING_STUDY}/profile.txt", caption="../report/scaling_profile.rst",
                        category="Contact scaling"),
            stats=f"results/{SCALING_STUDY}/profile.prof",
        params:
            subdomains=SCALING_N,
            elements=int(SCALING_PROFILE["elements"]),
            method=SCALING_PROFILE.get("method", "active-set"),
            top=int(SCALING_PROFILE.get("top", 30)),
            options=scaling_options,
        log:
            f"logs/{SCALING_STUDY}/profile.log",
        threads: scaling_threads
        script:
            "../scripts/scaling_profile.py"
