# Multibody studies (kind table_4, problem (4.32)): the thesis's Tables 4.1 / 4.2 with our
# numbers beside the printed ones, the Section 4.4 figures and the reports beyond them
# (kind "growth"), all listed in the config (`tables`, `figures`, config/table_4.yaml);
# rule all asks for those whose method is in the config (common.smk), so a study without
# hybrid runs has no table 4.2.


rule table_4:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_inputs(config["tables"][wc.table], wc.table, MULTIBODY_THESIS_KEYS),
    output:
        md="reports/{study}/{table}.md",
        md_html=report("reports/{study}/{table}.html", caption="../report/table_4.rst", category="Chapter 4: multibody"),
        tex="reports/{study}/{table}.tex",
    wildcard_constraints:
        table="|".join(config["tables"]),
    params:
        table=lambda wc: table_4_params(wc.table),
        contacts=CONTACTS,
        cases=[list(case) for case in CASES],
        base=list(CASES[0]),
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
        "../scripts/make_table_4.py"


rule figure_4:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_inputs(config["figures"][wc.figure], None, MULTIBODY_THESIS_KEYS),
    output:
        report("reports/{study}/{figure}.png", caption="../report/figure_4.rst", category="Chapter 4: multibody"),
    wildcard_constraints:
        figure="|".join(config["figures"]),
    params:
        figure=lambda wc: studies_workflow.sorted_keys(config["figures"][wc.figure]),
        contacts=CONTACTS,
        base=list(CASES[0]),
    log:
        "logs/{study}/{figure}.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/plot_figure_4.py"


# Table 4.2 evidence (ddstudies.optimal): per case small enough (system size <= max_n), PCR's
# iterations, the fewest iterations ANY Krylov method with the preconditioner (4.11) can need
# for the same load (exact minimal residual over the preconditioned Krylov space), the
# extreme eigenvalues of the preconditioned operator and the thesis's count; the finding
# below the table is computed from these rows.
rule table_4_2_optimal:
    input:
        thesis=thesis_table("table_4_2"),
    output:
        md="reports/{study}/table_4_2_optimal.md",
        md_html=report("reports/{study}/table_4_2_optimal.html", caption="../report/table_4_2_optimal.rst",
                  category="Chapter 4: multibody"),
        json="reports/{study}/table_4_2_optimal.json",
    params:
        cases=" ".join(f"--case {b},{s},{e}" for b, s, e in CASES),
        contacts=" ".join(CONTACTS),
        f=config["f"],
        rtol=config["rtol"],
        presets=" ".join(studies_workflow.rule_sets()),
        max_n=4000,
    log:
        "logs/{study}/table_4_2_optimal.log",
    threads: 1
    conda:
        "../envs/ddsolve.yaml"
    shell:
        "python -m ddstudies.optimal {params.cases} --contacts {params.contacts} "
        "--thesis {input.thesis} --f '{params.f}' --rtol {params.rtol} --presets {params.presets} "
        "--max-n {params.max_n} "
        "--out {output.md} > {log} 2>&1 "
        "&& python -m ddstudies.report.html {output.md} {output.md_html}"


# Table 4.1 readings (ddstudies.fetifeti_readings): exact FETI-FETI condition numbers of the
# small cases under the readings of the thesis's open points (projection, scaling of B_gl at
# body cross points, redundancy of the global multipliers); the closing paragraph compares
# the closest reading with the thesis (computed). docs/findings.md cites this file.
rule table_4_1_readings:
    input:
        thesis=thesis_table("table_4_1"),
    output:
        md="reports/{study}/table_4_1_readings.md",
        md_html=report("reports/{study}/table_4_1_readings.html", caption="../report/table_4_1_readings.rst",
                  category="Chapter 4: multibody"),
        json="reports/{study}/table_4_1_readings.json",
    params:
        cases=" ".join(f"--case {b},{s},{e}" for b, s, e in CASES),
        contacts=" ".join(CONTACTS),
        f=config["f"],
        max_n=1100,
    log:
        "logs/{study}/table_4_1_readings.log",
    threads: 1
    conda:
        "../envs/ddsolve.yaml"
    shell:
        "python -m ddstudies.fetifeti_readings {params.cases} --contacts {params.contacts} "
        "--thesis {input.thesis} --f '{params.f}' --max-n {params.max_n} --out {output.md} > {log} 2>&1 "
        "&& python -m ddstudies.report.html {output.md} {output.md_html}"
