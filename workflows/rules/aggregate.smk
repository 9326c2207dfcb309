# All result files of the study -> one CSV, one row per run.


rule aggregate:
    input:
        case_files,
    output:
        "results/{study}/summary.csv",
    log:
        "logs/{study}/aggregate.log",
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/aggregate.py"
