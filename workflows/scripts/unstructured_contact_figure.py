"""Snakemake script of rule unstructured_contact_figure: solve one unstructured contact case, draw its solution
with the METIS partition and the active set (ddstudies.report.unstructured_contact).

Inputs from Snakemake: params.spec (the ProblemSpec mapping), output[0] (PNG), log[0], threads.
"""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(snakemake.threads)  # noqa: F821

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    from pathlib import Path

    import numpy as np

    from ddsolve.io.hdf5 import atomic_target
    from ddstudies.report.contact_plots import solve_contact_case
    from ddstudies.report.unstructured_contact import plot_unstructured_contact

    sm = snakemake  # noqa: F821
    spec = dict(sm.params.spec)
    problem, solution = solve_contact_case(spec)
    kkt = problem.kkt(solution.u, solution.lam)
    print("spec:", spec, "\n", solution.reason, f"KKT residual {kkt.max:.2e}", flush=True)
    if not solution.converged:
        raise RuntimeError(f"contact figure: {spec['method']} did not converge: {solution.reason}")
    n_sub = 2 * int(spec["parts"])
    title = (f"Contact (3.1) on a netgen mesh (maxh {spec['maxh']:g}, refine {spec['refine']}), "
             f"{problem.sub.ndof:,} dofs, {n_sub} METIS subdomains: {spec['method']} (rule set default), "
             f"{int(np.count_nonzero(solution.active))} active pairs, KKT residual {kkt.max:.1e}")
    fig = plot_unstructured_contact(problem, solution, None, title=title)
    with atomic_target(Path(sm.output[0])) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
