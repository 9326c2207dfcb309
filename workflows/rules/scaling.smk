# Scaling study of the contact solvers (kind scaling, config/scaling.yaml):
#   snakemake --cores 2 --configfile config/scaling.yaml
# Helpers: common.smk. (`snakemake scaling ...` names the target alone.)
#   results/<study>/<method>/N<N>_m<m>.h5     one case (ddsolve.io.hdf5 layout)
#   results/<study>/summary.csv               all case files
#   reports/<study>/scaling.csv, scaling.md   table, exponent fits, targets
#   reports/<study>/scaling.png               time against dofs
#   reports/<study>/profile.txt               cProfile top functions


rule scaling:
    input:
        targets(),


rule scaling_case:
    output:
        f"results/{STUDY}/{{method}}/N{{N}}_m{{m}}.h5",
    wildcard_constraints:
        method="|".join(config["methods"]),
        N=r"\d+",
        m=r"\d+",
    params:
        options=scaling_options,
    log:
        f"logs/{STUDY}/{{method}}/N{{N}}_m{{m}}.log",
    threads: scaling_threads
    resources:
        tasks=1,
        mem_mb=scaling_mem_mb,
        runtime=120,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/scaling_case.py"


rule scaling_summary:
    input:
        scaling_case_files(),
    output:
        summary=f"results/{STUDY}/summary.csv",
        manifest=f"results/{STUDY}/summary.sha256",
        table=f"reports/{STUDY}/scaling.csv",
        markdown=f"reports/{STUDY}/scaling.md",
        markdown_html=report(f"reports/{STUDY}/scaling.html", caption="../report/scaling_table.rst",
                        category="Contact scaling"),
    params:
        targets=studies_workflow.sorted_keys(config.get("targets", {})),
    log:
        f"logs/{STUDY}/summary.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/scaling_summary.py"


rule scaling_plot:
    input:
        f"results/{STUDY}/summary.csv",
    output:
        report(f"reports/{STUDY}/scaling.png", caption="../report/scaling_plot.rst", category="Contact scaling"),
    log:
        f"logs/{STUDY}/plot.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/scaling_plot.py"


rule scaling_profile:
    input:
        # after the timed cases, so that it does not run beside one of them
        scaling_case_files(),
    output:
        text=report(f"reports/{STUDY}/profile.txt", caption="../report/scaling_profile.rst",
                    category="Contact scaling"),
        stats=f"results/{STUDY}/profile.prof",
    params:
        subdomains=int(config["subdomains"]),
        elements=int(SCALING_PROFILE["elements"]),
        method=SCALING_PROFILE.get("method", "active-set"),
        top=int(SCALING_PROFILE.get("top", 30)),
        options=scaling_options,
    log:
        f"logs/{STUDY}/profile.log",
    threads: scaling_threads
    resources:
        tasks=1,
        mem_mb=scaling_mem_mb,
        runtime=120,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/scaling_profile.py"
