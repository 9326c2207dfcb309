"""Snakemake script of rule solve_case: solve one case, write its HDF5 file.

Inputs from Snakemake: params.spec (the ProblemSpec mapping), output[0], log[0], threads.
"""
import os

# Keep BLAS/OpenMP inside the job's thread budget (set before numpy is imported).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(snakemake.threads)  # noqa: F821

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    from ddsolve.api import solve
    from ddsolve.io.hdf5 import write_result
    from ddsolve.spec import ProblemSpec

    spec = ProblemSpec.from_mapping(dict(snakemake.params.spec))  # noqa: F821
    print("spec:", spec.to_dict(), flush=True)
    result = solve(spec)
    print("result:", result.to_dict(), flush=True)
    write_result(snakemake.output[0], spec, result)  # noqa: F821
