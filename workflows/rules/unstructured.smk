# Unstructured study (kind unstructured, config/unstructured.yaml):
#   snakemake --cores 2 --configfile config/unstructured.yaml
# Helpers: common.smk. (`snakemake unstructured ...` names the target alone.)
#   results/<study>/<problem>/r<refine>.csv      one job: every method of the problem on one mesh
#   results/<study>/summary.csv                  all jobs
#   reports/<study>/unstructured.csv, .md        table (ratios to the direct peer), exponent fits, targets
#   reports/<study>/unstructured.png             time against dofs
# With config `cond_law` (condition numbers on METIS partitions, ddstudies.bench.cond_law):
#   results/<study>/cond/<method>/h<maxh>_r<refine>_P<parts>.h5   one solve (ddsolve.solve, cond=True)
#   results/<study>/cond/summary.csv, summary.sha256              every case, validated (aggregate.py)
#   reports/<study>/cond_law.md, .csv, .png                       table, fitted laws, log plot
# With config `contact_figure`:
#   reports/<study>/contact_solution.png         one contact solution, its METIS partition and active set


rule unstructured:
    input:
        targets(),


rule unstructured_case:
    output:
        f"results/{STUDY}/{{problem}}/r{{refine}}.csv",
    wildcard_constraints:
        problem="poisson|contact",
        refine=r"\d+",
    params:
        case=lambda wc: studies_workflow.sorted_keys(unstructured_case(wc)),
    log:
        f"logs/{STUDY}/{{problem}}/r{{refine}}.log",
    threads: scaling_threads
    resources:
        tasks=1,
        mem_mb=lambda wildcards: 8000 if int(wildcards.refine) >= 4 else 4000,
        runtime=lambda wildcards: 120 if int(wildcards.refine) >= 4 else 30,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/unstructured_case.py"


rule unstructured_summary:
    input:
        unstructured_case_files(),
    output:
        summary=f"results/{STUDY}/summary.csv",
        table=f"reports/{STUDY}/unstructured.csv",
        table_html=report(f"reports/{STUDY}/unstructured_table.html", caption="../report/unstructured_table.rst",
                     category="Unstructured meshes"),
        markdown=f"reports/{STUDY}/unstructured.md",
        markdown_html=report(f"reports/{STUDY}/unstructured.html", caption="../report/unstructured_summary.rst",
                        category="Unstructured meshes"),
    params:
        targets=studies_workflow.sorted_keys(config.get("targets", {})),
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    log:
        f"logs/{STUDY}/summary.log",
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/unstructured_summary.py"


rule unstructured_plot:
    input:
        f"results/{STUDY}/summary.csv",
    output:
        report(f"reports/{STUDY}/unstructured.png", caption="../report/unstructured_plot.rst",
               category="Unstructured meshes"),
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    log:
        f"logs/{STUDY}/plot.log",
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/unstructured_plot.py"


rule unstructured_cond_case:
    output:
        f"results/{STUDY}/cond/{{method}}/{{stem}}.h5",
    wildcard_constraints:
        method="fetidp|bddc",
        stem=r"h[0-9.e+-]+_r\d+_P\d+(_[a-z-]+)?",
    params:
        spec=lambda wc: studies_workflow.sorted_keys(unstructured_cond_spec(wc)),
    log:
        f"logs/{STUDY}/cond/{{method}}/{{stem}}.log",
    threads: 1
    resources:
        tasks=1,
        mem_mb=lambda wc: studies_workflow.case_mem_mb(unstructured_cond_size(wc)),
        runtime=lambda wc: studies_workflow.case_runtime(unstructured_cond_size(wc)),
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/solve_case.py"


rule unstructured_cond_aggregate:
    input:
        unstructured_cond_files,
    output:
        summary=f"results/{STUDY}/cond/summary.csv",
        manifest=f"results/{STUDY}/cond/summary.sha256",
    log:
        f"logs/{STUDY}/cond/aggregate.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/aggregate.py"


rule unstructured_cond_law:
    input:
        f"results/{STUDY}/cond/summary.csv",
    output:
        markdown=f"reports/{STUDY}/cond_law.md",
        markdown_html=report(f"reports/{STUDY}/cond_law.html", caption="../report/unstructured_cond_table.rst",
                        category="Unstructured meshes"),
        table=f"reports/{STUDY}/cond_law.csv",
        plot=report(f"reports/{STUDY}/cond_law.png", caption="../report/unstructured_cond_plot.rst",
                    category="Unstructured meshes"),
    params:
        cond_law=studies_workflow.sorted_keys(config.get("cond_law", {})),
    log:
        f"logs/{STUDY}/cond/law.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/unstructured_cond_law.py"


rule unstructured_contact_figure:
    output:
        report(f"reports/{STUDY}/contact_solution.png", caption="../report/unstructured_contact.rst",
               category="Unstructured meshes"),
    params:
        spec=lambda wc: studies_workflow.sorted_keys(unstructured_figure_spec(wc)),
    log:
        f"logs/{STUDY}/contact_figure.log",
    threads: 1
    resources:
        tasks=1,
        mem_mb=lambda wc: studies_workflow.case_mem_mb(FIGURE_SIZE),
        runtime=lambda wc: studies_workflow.case_runtime(FIGURE_SIZE),
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/unstructured_contact_figure.py"
