# Unstructured study (kind unstructured, config/unstructured.yaml):
#   snakemake --cores 2 --configfile config/unstructured.yaml
# Helpers: common.smk. (`snakemake unstructured ...` names the target alone.)
#   results/<study>/<problem>/r<refine>.csv      one job: every method of the problem on one mesh
#   results/<study>/summary.csv                  all jobs
#   reports/<study>/unstructured.csv, .md        table (ratios to the direct peer), exponent fits, targets
#   reports/<study>/unstructured.png             time against dofs


rule unstructured:
    input:
        targets(),


rule unstructured_case:
    output:
        f"results/{STUDY}/{{problem}}/r{{refine}}.csv",
    wildcard_constraints:
        problem="poisson|contact",
        refine=r"\d+",
    params:
        case=unstructured_case,
    log:
        f"logs/{STUDY}/{{problem}}/r{{refine}}.log",
    threads: scaling_threads
    resources:
        tasks=1,
        mem_mb=lambda wildcards: 8000 if int(wildcards.refine) >= 4 else 4000,
        runtime=lambda wildcards: 120 if int(wildcards.refine) >= 4 else 30,
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/unstructured_case.py"


rule unstructured_summary:
    input:
        unstructured_case_files(),
    output:
        summary=f"results/{STUDY}/summary.csv",
        table=report(f"reports/{STUDY}/unstructured.csv", caption="../report/unstructured_table.rst",
                     category="Unstructured meshes"),
        markdown=f"reports/{STUDY}/unstructured.md",
    params:
        targets=config.get("targets", {}),
    resources:
        tasks=1,
        mem_mb=2000,
        runtime=15,
    log:
        f"logs/{STUDY}/summary.log",
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/unstructured_summary.py"


rule unstructured_plot:
    input:
        f"results/{STUDY}/summary.csv",
    output:
        report(f"reports/{STUDY}/unstructured.png", caption="../report/unstructured_plot.rst",
               category="Unstructured meshes"),
    resources:
        tasks=1,
        mem_mb=2000,
        runtime=15,
    log:
        f"logs/{STUDY}/plot.log",
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/unstructured_plot.py"
