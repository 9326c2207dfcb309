# Numerical stability stress study (kind stress, config/stress.yaml): coefficient jumps,
# tight tolerances, many subdomains / large H/h / many floating bodies, contact extremes
# and degenerate input, each case judged PASS/FAIL against the criterion it states.
# The cases: the catalog of ddstudies.stress.catalogue, tier `tier` (common.smk).
#
#   results/<study>/cases/<series>.json   one JSON list of case records per series (rule stress_series;
#                                         per group in the quick tier)
#   results/<study>/stress.csv            every case with its outcome (rule stress_report)
#   reports/<study>/stress.md             one row per case: claim, iterations, cond, true vs
#                                         recursive residual, error vs direct, PASS/FAIL
#   logs/<study>/cases/<series>.log, logs/<study>/stress_report.log


rule stress_series:
    output:
        f"results/{STUDY}/cases/{{series}}.json",
    params:
        cases=lambda wc: studies_workflow.sorted_keys(stress_series_cases(wc)),
        timeout=config["case_timeout"],
    wildcard_constraints:
        series="|".join(re.escape(s) for s in STRESS_SERIES),
    log:
        f"logs/{STUDY}/cases/{{series}}.log",
    threads: 1
    resources:
        tasks=1,
        mem_mb=STRESS_MEM_MB,
        runtime=stress_runtime,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/stress_series.py"


rule stress_report:
    input:
        expand(f"results/{STUDY}/cases/{{series}}.json", series=STRESS_SERIES),
    output:
        md=f"reports/{STUDY}/stress.md",
        md_html=report(f"reports/{STUDY}/stress.html", caption="../report/stress.rst", category="Stress study"),
        csv=f"results/{STUDY}/stress.csv",
    log:
        f"logs/{STUDY}/stress_report.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/stress_report.py"
