"""Snakemake script of rule bench_case: run one method at one rtol, write its HDF5 file.

Inputs from Snakemake: input.reference, params.spec (ProblemSpec mapping), params.load_cells,
params.rtol (None for "exact"), params.options (maxiter, threads, direct, repeats),
wildcards.solver, output[0], log[0], threads.
"""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(snakemake.threads)  # noqa: F821

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import logging

    logging.basicConfig(stream=log, level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    from ddstudies.bench.case import run_case
    from ddstudies.bench.methods import RunOptions
    from ddstudies.bench.problems import build_problem
    from ddstudies.bench.store import read_reference, write_case

    sm = snakemake  # noqa: F821
    opts = dict(sm.params.options)
    repeats = int(opts.pop("repeats"))
    problem = build_problem(dict(sm.params.spec), load_cells=sm.params.load_cells)
    record = run_case(problem, sm.wildcards.solver, sm.params.rtol, read_reference(sm.input.reference),
                      RunOptions(**opts), repeats=repeats)
    print("result:", record.to_dict(), flush=True)
    write_case(sm.output[0], problem.spec.to_dict(), sm.wildcards.solver, sm.params.rtol, record, repeats)
