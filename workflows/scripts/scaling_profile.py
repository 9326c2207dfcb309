"""Snakemake script of rule scaling_profile: cProfile of one contact solve -> profile.txt (+ raw .prof).

Inputs from Snakemake: params.subdomains, params.elements, params.method, params.top, params.options,
output.text, output.stats, log[0].
"""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import logging
    from pathlib import Path

    logging.basicConfig(stream=log, level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    from ddstudies.workflow import write_text
    from ddstudies.bench.scaling import profile_case, solver_options

    sm = snakemake  # noqa: F821
    opts = dict(sm.params.options)
    text = profile_case(int(sm.params.subdomains), int(sm.params.elements), sm.params.method,
                        **solver_options(opts), top=int(sm.params.top), stats_path=sm.output.stats)
    Path(sm.output.text).parent.mkdir(parents=True, exist_ok=True)
    write_text(sm.output.text, text)
    print(text, flush=True)
