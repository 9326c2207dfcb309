"""Snakemake script of rule figure_5_2: solve one contact case, draw Figure 5.2 and the contact plot.

Inputs from Snakemake: params.spec (the ProblemSpec mapping), output.surface,
output.contact (PNG), output.csv (u^1, u^2, lambda along Gamma_c), log[0], threads.
"""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(snakemake.threads)  # noqa: F821

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    from ddstudies.report.contact_plots import (contact_line, membrane_surfaces, plot_contact_line,
                                              plot_membranes, solve_contact_case)

    sm = snakemake  # noqa: F821
    spec = dict(sm.params.spec)
    problem, solution = solve_contact_case(spec)
    print("spec:", spec, "\n", solution.reason, flush=True)
    n, m = spec["subdomains"], spec["elements"]
    rules = f"{spec.get('preset', 'default')} rules"          # the rule set (ddsolve.presets) named, as the tables
    plot_membranes(membrane_surfaces(problem, solution.u), sm.output.surface,
                   title=f"Figure 5.2: solution of (3.1), $N_{{sub}} = {n * n}$, $H/h = {m}$ "
                         f"({spec['method']}, {rules})")
    line = contact_line(problem, solution)
    line.to_csv(sm.output.csv, index=False)
    plot_contact_line(line, sm.output.contact,
                      title=f"$\\Gamma_c$: $N_{{sub}} = {n * n}$, $H/h = {m}$, {rules}, "
                            f"{int(line['active'].sum())} of {len(line)} pairs active")
