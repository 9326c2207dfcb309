# Multibody studies (problem (4.32)): the thesis's Tables 4.1 / 4.2 with our numbers
# beside the printed ones, and the Section 4.4 figures. The tables and figures are
# listed in common.smk (TABLES_4, FIGURES_4); rule all asks for those whose method is
# in the config (report_files), so a study without hybrid runs has no table 4.2.

# Reports beyond the thesis's tables: both methods along the H_b/H_s sweep (the thesis
# stops at 18; config/table_4.yaml goes on to 48), with the growth of FETI-FETI's cond
# and iterations and of the hybrid iterations and the fitted laws (kind "growth").
# Registered here, before the rules, so that rule all (report_files) asks for them and
# the rules' wildcard constraints include them; "method" gates them on hybrid runs,
# "thesis" names the transcriptions read (table 4.1 for FETI-FETI, 4.2 for the hybrid).
TABLES_4["table_4_growth"] = {
    "method": "hybrid", "kind": "growth", "start": 4, "thesis": ["table_4_1", "table_4_2"],
    "title": "Beyond Tables 4.1/4.2: FETI-FETI and hybrid along H_b/H_s, growth and fitted laws"}
FIGURES_4["figure_iterations_vs_HbHs"] = {
    "method": "hybrid", "kind": "growth", "thesis": ["table_4_1", "table_4_2"],
    "title": "FETI-FETI (PCG) and hybrid (PCR) iterations against $H_b/H_s$"}


def thesis_inputs(entry, default):
    """The thesis transcriptions of a TABLES_4 / FIGURES_4 entry ("thesis": a name or a list)."""
    names = entry.get("thesis", default)
    return [thesis_table(name) for name in ([names] if isinstance(names, str) else names)]


rule table_4:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_inputs(TABLES_4[wc.table], wc.table),
    output:
        md=report("reports/{study}/{table}.md", caption="../report/table_4.rst", category="Chapter 4: multibody"),
        tex="reports/{study}/{table}.tex",
    wildcard_constraints:
        table="|".join(TABLES_4),
    params:
        table=lambda wc: TABLES_4[wc.table],
        contacts=CONTACTS,
        cases=[list(case) for case in CASES],
        base=list(CASES[0]),
    log:
        "logs/{study}/{table}.log",
    script:
        "../scripts/make_table_4.py"


rule figure_4:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_inputs(FIGURES_4[wc.figure], None),
    output:
        report("reports/{study}/{figure}.png", caption="../report/figure_4.rst", category="Chapter 4: multibody"),
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
