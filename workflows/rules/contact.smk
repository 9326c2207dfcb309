# Contact studies (kind contact, problem (3.1), thesis Chapters 5 and 6): Tables 5.1 / 6.1
# with our numbers beside the printed ones (config `tables`), the comparison of both
# methods per grid, and Figure 5.2 (config `figure_5_2`). Targets: common.smk.


rule contact_table:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_table(wc.table),
    output:
        md="reports/{study}/{table}.md",
        md_html=report("reports/{study}/{table}.html", caption="../report/contact_table.rst",
                  category="Chapters 5 and 6: contact"),
        tex="reports/{study}/{table}.tex",
    wildcard_constraints:
        table="|".join(config["tables"]),
    log:
        "logs/{study}/{table}.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/make_contact_table.py"


rule contact_comparison:
    input:
        summary="results/{study}/summary.csv",
        table_5_1=thesis_table("table_5_1") if "thesis_tables" in config else [],
        table_6_1=thesis_table("table_6_1") if "thesis_tables" in config else [],
    output:
        md="reports/{study}/comparison.md",
        md_html=report("reports/{study}/comparison.html", caption="../report/contact_comparison.rst",
                  category="Chapters 5 and 6: contact"),
        tex="reports/{study}/comparison.tex",
        png=report("reports/{study}/comparison.png", caption="../report/contact_comparison.rst",
                   category="Chapters 5 and 6: contact"),
    log:
        "logs/{study}/comparison.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/make_contact_comparison.py"


rule figure_5_2:
    output:
        surface=report("reports/{study}/figure_5_2_surface.png", caption="../report/figure_5_2.rst",
                       category="Chapters 5 and 6: contact"),
        contact=report("reports/{study}/figure_5_2_contact.png", caption="../report/contact_plot.rst",
                       category="Chapters 5 and 6: contact"),
        csv="reports/{study}/figure_5_2_contact.csv",
    params:
        spec=figure_5_2_spec(),
    log:
        "logs/{study}/figure_5_2.log",
    threads: 1
    resources:
        tasks=1,
        mem_mb=studies_workflow.case_mem_mb(FIGURE_5_2_SIZE),
        runtime=studies_workflow.case_runtime(FIGURE_5_2_SIZE),
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/plot_figure_5_2.py"


# Active set method against SMALBE at matched accuracy (ddstudies.contact_precision): the
# study's small grids (N * H/h <= 32) solved by both methods at rtol = eps 1e-4 .. 1e-8 under
# every rule set (default and, where ddsolve has it, the thesis preset): total iterations and
# time against the KKT residual reached; the verdict per rule set is computed.
rule contact_work_precision:
    output:
        md="reports/{study}/work_precision.md",
        md_html=report("reports/{study}/work_precision.html", caption="../report/contact_work_precision.rst",
                  category="Chapters 5 and 6: contact"),
        csv="reports/{study}/work_precision.csv",
        png=report("reports/{study}/work_precision.png", caption="../report/contact_work_precision.rst",
                   category="Chapters 5 and 6: contact"),
    params:
        grids=" ".join(f"--grid {g}" for g in studies_workflow.contact_precision_grids(
            _as_list(config["subdomains"]), _as_list(config["elements"]))),
        presets=" ".join(studies_workflow.rule_sets()),
        f=config["f"],
        maxiter=config["maxiter"],
    log:
        "logs/{study}/work_precision.log",
    threads: 1
    conda:
        "../envs/ddsolve.yaml"
    shell:
        "python -m ddstudies.contact_precision {params.grids} --rtols 1e-4 1e-5 1e-6 1e-7 1e-8 "
        "--presets {params.presets} --f '{params.f}' --maxiter {params.maxiter} --out {output.md} > {log} 2>&1 "
        "&& python -m ddstudies.report.html {output.md} {output.md_html}"
