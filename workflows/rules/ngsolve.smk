# DDInverse against NGSolve's solvers (kind ngsolve, config/ngsolve.yaml):
#   snakemake --cores 2 --configfile config/ngsolve.yaml
# One job runs every case and solver one after another (ddstudies.ngsolve_bench), so that
# the timings are taken under the same conditions; it takes all the cores given to Snakemake.
#   results/<study>/ngsolve.csv      one row per (solver, order, dofs), load average included
#   reports/<study>/ngsolve.md       table and the targets
#   reports/<study>/ngsolve.png      setup + solve time against dofs, one panel per order


rule ngsolve:
    input:
        targets(),


rule ngsolve_bench:
    output:
        csv=f"results/{STUDY}/ngsolve.csv",
        markdown=f"reports/{STUDY}/ngsolve.md",
        markdown_html=report(f"reports/{STUDY}/ngsolve.html", caption="../report/ngsolve_table.rst", category="NGSolve"),
        plot=report(f"reports/{STUDY}/ngsolve.png", caption="../report/ngsolve_plot.rst", category="NGSolve"),
    params:
        config=lambda wc: json.dumps({key: config[key] for key in NGSOLVE_KEYS if key in config}, sort_keys=True),
    log:
        f"logs/{STUDY}/ngsolve.log",
    threads: scaling_threads
    resources:
        tasks=1,
        mem_mb=16000,
        runtime=240,
    conda:
        "../envs/ddsolve.yaml"
    shell:
        "OMP_NUM_THREADS=1 python -m ddstudies.ngsolve_bench '{params.config}' {output.csv} {output.markdown} "
        "{output.plot} > {log} 2>&1 "
        "&& python -m ddstudies.report.html {output.markdown} {output.markdown_html}"
