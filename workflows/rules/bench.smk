# Work-precision benchmark (kind bench, config/bench.yaml):
#   snakemake --cores 2 --configfile config/bench.yaml
# Helpers and the case list: common.smk. (`snakemake bench ...` names the target alone.)
#   results/<study>/<problem>/reference.h5
#   results/<study>/<problem>/<solver>/<tol>.h5   tol = rtol1e-06, ... or "exact"
#   results/<study>/summary.csv                   all collected case files
#   reports/<study>/work_precision.csv, .png      summary table and plot


rule bench:
    input:
        targets(),


rule bench_reference:
    output:
        f"results/{STUDY}/{{kind}}/reference.h5",
    wildcard_constraints:
        kind=BENCH_PROBLEMS,
    params:
        spec=bench_reference_spec,
        load_cells=lambda wc: config["problems"][wc.kind].get("load_cells"),
    log:
        f"logs/{STUDY}/{{kind}}/reference.log",
    threads: config["threads"]
    resources:
        tasks=1,
        mem_mb=lambda wc: studies_workflow.case_mem_mb(BENCH_SIZES[wc.kind], factor=4),
        runtime=lambda wc: studies_workflow.case_runtime(BENCH_SIZES[wc.kind], factor=4, floor=30),
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/bench_reference.py"


rule bench_case:
    input:
        reference=f"results/{STUDY}/{{kind}}/reference.h5",
    output:
        f"results/{STUDY}/{{kind}}/{{solver}}/{{tol}}.h5",
    wildcard_constraints:
        kind=BENCH_PROBLEMS,
        solver=r"[A-Za-z0-9_.+-]+",
        tol="exact|" + "|".join(re.escape(t) for t in BENCH_RTOLS),
    params:
        spec=bench_spec,
        load_cells=lambda wc: config["problems"][wc.kind].get("load_cells"),
        rtol=lambda wc: BENCH_RTOLS.get(wc.tol),
        options=bench_options,
    log:
        f"logs/{STUDY}/{{kind}}/{{solver}}/{{tol}}.log",
    threads: config["threads"]
    resources:
        tasks=1,
        mem_mb=lambda wc: studies_workflow.case_mem_mb(BENCH_SIZES[wc.kind], factor=4),
        runtime=lambda wc: studies_workflow.case_runtime(BENCH_SIZES[wc.kind], factor=4, floor=30),
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/bench_case.py"


rule bench_summary:
    input:
        bench_case_files(),
    output:
        summary=f"results/{STUDY}/summary.csv",
        manifest=f"results/{STUDY}/summary.sha256",
        table=f"reports/{STUDY}/work_precision.csv",
        table_html=report(f"reports/{STUDY}/work_precision_table.html", caption="../report/bench_table.rst",
                     category="Work-precision benchmark"),
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
        "../scripts/bench_summary.py"


rule bench_plot:
    input:
        f"reports/{STUDY}/work_precision.csv",
    output:
        report(f"reports/{STUDY}/work_precision.png", caption="../report/bench_plot.rst",
               category="Work-precision benchmark"),
    params:
        time=config["plot_time"],
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
        "../scripts/bench_plot.py"
