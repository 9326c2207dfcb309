# Distributed-solve benchmark (kind mpi, config/mpi.yaml): a Poisson case (and optionally a
# contact case, the active set method), each with P = ranks.
#   snakemake --cores 2 --configfile config/mpi.yaml
# Not part of the default reproduction (config/default.yaml does not list it).
#   results/<study>/<method>/P<P>.json    the JSON of `mpiexec -n P ddsolve solve --json` (+ load average)
#   reports/<study>/mpi.csv, mpi.md       speed-up of the solve phase, comm counts, the alpha-beta model
#                                         (FETI-DP/BDDC), the contact case's measured table


rule mpi:
    input:
        targets(),


rule mpi_case:
    input:
        mpi_previous_case,
    output:
        f"results/{STUDY}/{{method}}/P{{P}}.json",
    wildcard_constraints:
        method="|".join(re.escape(method) for method in mpi_methods()),
        P=r"[1-9]\d*",
    params:
        spec=mpi_spec,
        repeats=int(config["repeats"]),
        launcher=config["launcher"],
    resources:
        tasks=lambda wildcards: int(wildcards.P),
        # the SLURM plugin refuses an MPI job of one task ("'tasks' must be greater than 1"): P = 1 declares none
        # (an empty mpi: sbatch --ntasks=1); the script takes the launcher from params.launcher
        mpi=lambda wildcards: config["launcher"] if int(wildcards.P) > 1 else "",
        # one core per rank: with threads = P alone the plugin asked for P tasks x P cpus per task
        cpus_per_task=1,
        mem_mb=lambda wildcards: 4000 * int(wildcards.P),
        runtime=60,
    threads: lambda wildcards: int(wildcards.P)
    log:
        f"logs/{STUDY}/{{method}}/P{{P}}.log",
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/mpi_case.py"


rule mpi_summary:
    input:
        mpi_case_files(),
    output:
        table=f"reports/{STUDY}/mpi.csv",
        markdown=f"reports/{STUDY}/mpi.md",
        markdown_html=report(f"reports/{STUDY}/mpi.html", caption="../report/mpi.rst", category="MPI"),
    localrule: True
    resources:
        tasks=1,
        mem_mb=REPORT_MEM_MB,
        runtime=REPORT_RUNTIME,
    log:
        f"logs/{STUDY}/summary.log",
    conda:
        "../envs/ddsolve.yaml"
    script:
        "../scripts/mpi_summary.py"
