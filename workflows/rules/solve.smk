# One job per case: solve it and write its result file.


rule solve_case:
    output:
        f"results/{CASE}.h5",
    params:
        spec=case_spec,
    log:
        f"logs/{CASE}.log",
    threads: 1
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/solve_case.py"
