# Summary CSV -> thesis-style table (Markdown, LaTeX) and the cond vs H/h plot.


rule table:
    input:
        "results/{study}/summary.csv",
    output:
        md="reports/{study}/table.md",
        md_html=report("reports/{study}/table.html", caption="../report/poisson_table.rst", category="Poisson"),
        tex="reports/{study}/table.tex",
    params:
        methods=config["methods"],
    log:
        "logs/{study}/table.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/make_table.py"


rule plot_cond:
    input:
        "results/{study}/summary.csv",
    output:
        report("reports/{study}/cond_vs_Hh.png", caption="../report/poisson_cond.rst", category="Poisson"),
    params:
        methods=config["methods"],
    log:
        "logs/{study}/plot_cond.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/plot_cond.py"
