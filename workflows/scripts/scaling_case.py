"""Snakemake script of rule scaling_case: time one contact solver on one mesh, write its HDF5 file.

Inputs from Snakemake: wildcards.method, wildcards.N, wildcards.m, params.options (the options the
method reads: rtol and maxiter for active-set, direct and direct_threads for pdas; repeats and
repeat_budget for both), output[0], log[0].
"""
import os

# ddsolve's solvers run with one BLAS thread (threadpoolctl, as ddsolve.solve); the job reserves
# all of Snakemake's cores only so that no other case runs beside it.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import logging

    logging.basicConfig(stream=log, level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    from ddstudies.bench.scaling import case_params, run_scaling_case, solver_options
    from ddsolve.io.hdf5 import write_result

    sm = snakemake  # noqa: F821
    opts = dict(sm.params.options)
    N, m, method = int(sm.wildcards.N), int(sm.wildcards.m), sm.wildcards.method
    solver = solver_options(opts)
    record = run_scaling_case(N, m, method, **solver, repeats=int(opts["repeats"]),
                              repeat_budget=float(opts["repeat_budget"]))
    print("result:", record.to_dict(), flush=True)
    spec_options = {key: solver[key] for key in ("rtol", "maxiter") if key in solver}
    write_result(sm.output[0], case_params(N, m, method, **spec_options, repeats=int(opts["repeats"])), record)
