# Multibody studies (kind table_4, problem (4.32)): the thesis's Tables 4.1 / 4.2 with our
# numbers beside the printed ones, the Section 4.4 figures and the reports beyond them
# (kind "growth"), all listed in the config (`tables`, `figures`, config/table_4.yaml);
# rule all asks for those whose method is in the config (common.smk), so a study without
# hybrid runs has no table 4.2.


rule table_4:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_inputs(config["tables"][wc.table], wc.table),
    output:
        md=report("reports/{study}/{table}.md", caption="../report/table_4.rst", category="Chapter 4: multibody"),
        tex="reports/{study}/{table}.tex",
    wildcard_constraints:
        table="|".join(config["tables"]),
    params:
        table=lambda wc: config["tables"][wc.table],
        contacts=CONTACTS,
        cases=[list(case) for case in CASES],
        base=list(CASES[0]),
    log:
        "logs/{study}/{table}.log",
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/make_table_4.py"


rule figure_4:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_inputs(config["figures"][wc.figure], None),
    output:
        report("reports/{study}/{figure}.png", caption="../report/figure_4.rst", category="Chapter 4: multibody"),
    wildcard_constraints:
        figure="|".join(config["figures"]),
    params:
        figure=lambda wc: config["figures"][wc.figure],
        contacts=CONTACTS,
        base=list(CASES[0]),
    log:
        "logs/{study}/{figure}.log",
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/plot_figure_4.py"
