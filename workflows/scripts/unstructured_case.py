"""Snakemake script of rule unstructured_case: one (problem, refinement), every method -> one CSV.

Inputs from Snakemake: params.case (problem, maxh, refine, parts, methods, rtol, maxiter, cond, direct,
direct_threads, seed; see ddstudies.bench.unstructured.run_unstructured_case), output[0], log[0].
"""
import os

# ddsolve's solvers run with one BLAS thread (threadpoolctl, as ddsolve.solve); the job reserves
# all of Snakemake's cores only so that no other job runs beside it.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import logging

    logging.basicConfig(stream=log, level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    from ddstudies.aggregate import write_table
    from ddstudies.bench.unstructured import run_unstructured_case

    sm = snakemake  # noqa: F821
    df = run_unstructured_case(**dict(sm.params.case))
    write_table(df, sm.output[0])
    print(df.to_string(), flush=True)
