"""Snakemake script of rule stress_series: run the stress cases of one series, write their records.

Inputs from Snakemake: wildcards.series, params.cases (the series' StressCase fields as dicts),
params.timeout, output[0], log[0], threads.
Every case yields a record (a crash, an expected input error or a timeout included), so the
job itself only fails if the records cannot be written.
"""
import logging
import os

# Keep BLAS/OpenMP inside the job's thread budget (set before numpy is imported).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(snakemake.threads)  # noqa: F821

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    logging.basicConfig(stream=log, level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    from ddstudies.stress import StressCase, run_case, write_records

    series = snakemake.wildcards.series  # noqa: F821
    cases = [StressCase(**fields) for fields in snakemake.params.cases]  # noqa: F821
    if not cases:
        raise ValueError(f"no stress cases in series {series!r}")
    records = []
    for case in cases:
        record = run_case(case, timeout=float(snakemake.params.timeout))  # noqa: F821
        print(f"{case.name}: status={record['status']} converged={record['converged']} "
              f"iterations={record['iterations']} {record['reason'] or record['error']} "
              f"({record['seconds']:.2f} s)", flush=True)
        records.append(record)
    write_records(snakemake.output[0], records)  # noqa: F821
