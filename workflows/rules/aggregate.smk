# All result files of the study, each validated -> one CSV, one row per run, and the SHA-256 of
# each file (summary.sha256, checked when the workflow plans: docs/studies.md).


rule aggregate:
    input:
        case_files,
    output:
        summary="results/{study}/summary.csv",
        manifest="results/{study}/summary.sha256",
    log:
        "logs/{study}/aggregate.log",
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/aggregate.py"
