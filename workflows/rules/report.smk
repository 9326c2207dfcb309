# Summary CSV -> thesis-style table (Markdown, LaTeX) and the cond vs H/h plot.


rule table:
    input:
        "results/{study}/summary.csv",
    output:
        md="reports/{study}/table.md",
        tex="reports/{study}/table.tex",
    params:
        methods=config["methods"],
    log:
        "logs/{study}/table.log",
    script:
        "../scripts/make_table.py"


rule plot_cond:
    input:
        "results/{study}/summary.csv",
    output:
        "reports/{study}/cond_vs_Hh.png",
    params:
        methods=config["methods"],
    log:
        "logs/{study}/plot_cond.log",
    script:
        "../scripts/plot_cond.py"
