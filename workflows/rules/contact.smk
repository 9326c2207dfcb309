# Contact studies (problem (3.1), thesis Chapters 5 and 6): Tables 5.1 / 6.1 with our
# numbers beside the printed ones, the comparison of both methods per grid, and
# Figure 5.2. Rule all asks for these only when the config has problem: contact
# (report_files in common.smk calls contact_report_files).

#: Thesis tables shown when their method is in the config (ddsolve.report.contact_tables.CONTACT_TABLES).
CONTACT_TABLE_METHODS = {"table_5_1": "active-set", "table_6_1": "smalbe"}
#: Figure 5.2 of the thesis: the solution for N_sub = 16 (1/H = 4), H/h = 8, computed
#: here with the active set method (its own small solve, independent of the sweep).
FIGURE_5_2 = {"method": "active-set", "subdomains": 4, "elements": 8}


def figure_5_2_spec():
    """The ProblemSpec mapping of Figure 5.2: the study's shared keys, the case of FIGURE_5_2."""
    spec = {key: config[key] for key in SHARED_SPEC_KEYS if key in config}
    spec.update(problem="contact", bodies=2, **FIGURE_5_2)
    return spec


def contact_report_files():
    """The reports of a contact study (targets of rule all)."""
    methods = set(config["methods"])
    files = []
    for name, method in CONTACT_TABLE_METHODS.items():
        if method in methods:
            files += [f"reports/{STUDY}/{name}.md", f"reports/{STUDY}/{name}.tex"]
    if {"active-set", "smalbe"} <= methods:
        files += [f"reports/{STUDY}/comparison.{ext}" for ext in ("md", "tex", "png")]
    files += [f"reports/{STUDY}/figure_5_2_{part}" for part in ("surface.png", "contact.png", "contact.csv")]
    return files


rule contact_table:
    input:
        summary="results/{study}/summary.csv",
        thesis=lambda wc: thesis_table(wc.table),
    output:
        md=report("reports/{study}/{table}.md", caption="../report/contact_table.rst",
                  category="Chapters 5 and 6: contact"),
        tex="reports/{study}/{table}.tex",
    wildcard_constraints:
        table="|".join(CONTACT_TABLE_METHODS),
    log:
        "logs/{study}/{table}.log",
    script:
        "../scripts/make_contact_table.py"


rule contact_comparison:
    input:
        summary="results/{study}/summary.csv",
        table_5_1=thesis_table("table_5_1") if "thesis_tables" in config else [],
        table_6_1=thesis_table("table_6_1") if "thesis_tables" in config else [],
    output:
        md=report("reports/{study}/comparison.md", caption="../report/contact_comparison.rst",
                  category="Chapters 5 and 6: contact"),
        tex="reports/{study}/comparison.tex",
        png=report("reports/{study}/comparison.png", caption="../report/contact_comparison.rst",
                   category="Chapters 5 and 6: contact"),
    log:
        "logs/{study}/comparison.log",
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
    script:
        "../scripts/plot_figure_5_2.py"
