# Multibody studies (problem (4.32)): the thesis's Tables 4.1 / 4.2 with our numbers
# beside the printed ones, and the Section 4.4 figures. The tables and figures are
# listed in common.smk (TABLES_4, FIGURES_4); rule all asks for those whose method is
# in the config (report_files), so a study without hybrid runs has no table 4.2.


rule table_4:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_table(wc.table),
    output:
        md="reports/{study}/{table}.md",
        tex="reports/{study}/{table}.tex",
    wildcard_constraints:
        table="|".join(TABLES_4),
    params:
        table=lambda wc: TABLES_4[wc.table],
        contacts=CONTACTS,
        cases=[list(case) for case in CASES],
    log:
        "logs/{study}/{table}.log",
    script:
        "../scripts/make_table_4.py"


rule figure_4:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_table(FIGURES_4[wc.figure]["thesis"]),
    output:
        "reports/{study}/{figure}.png",
    wildcard_constraints:
        figure="|".join(FIGURES_4),
    params:
        figure=lambda wc: FIGURES_4[wc.figure],
        contacts=CONTACTS,
        base=list(CASES[0]),
    log:
        "logs/{study}/{figure}.log",
    script:
        "../scripts/plot_figure_4.py"
