# One job per case: solve it and write its result file.


rule solve_case:
    output:
        f"results/{CASE}.h5",
    params:
        spec=lambda wc: studies_workflow.sorted_keys(case_spec(wc)),
    log:
        f"logs/{CASE}.log",
    threads: 1
    resources:
        tasks=1,
        mem_mb=lambda wc: studies_workflow.case_mem_mb(case_size(wc)),
        runtime=lambda wc: studies_workflow.case_runtime(case_size(wc)),
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/solve_case.py"
