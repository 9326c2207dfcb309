"""Snakemake script of rule bench_reference: direct solves of a benchmark problem and its 2x refinement.

Inputs from Snakemake: params.spec (ProblemSpec mapping), params.load_cells, output[0], log[0], threads.
"""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(snakemake.threads)  # noqa: F821

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import logging

    logging.basicConfig(stream=log, level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    from threadpoolctl import threadpool_limits

    from ddstudies.bench.case import compute_reference
    from ddstudies.bench.problems import build_problem
    from ddstudies.bench.store import write_reference

    sm = snakemake  # noqa: F821
    with threadpool_limits(limits=sm.threads, user_api="blas"):
        problem = build_problem(dict(sm.params.spec), load_cells=sm.params.load_cells)
        reference = compute_reference(problem)
    write_reference(sm.output[0], problem.spec.to_dict(), reference)
    print("reference:", reference.info, "discretization error", reference.discretization_error, flush=True)
