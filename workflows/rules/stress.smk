# Numerical stability stress study (config/stress.yaml): coefficient jumps, tight
# tolerances, many subdomains / large H/h / many floating bodies, contact extremes and
# degenerate input, each case judged PASS/FAIL against the criterion it states.
#
# Included (workflows/rules/study.smk) for a study whose name starts with "stress",
# instead of the rules of the grid studies. The cases are the catalog of ddsolve.report.stress (tier "quick" for
# a study named "stress_quick", the test-suite sizes; tier "study" otherwise): the
# config schema admits no case lists, so the catalog lives in code. Each series job
# gets its cases in `params`, so a changed case reruns its series.
#
#   results/<study>/cases/<series>.json   one JSON list of case records per series (rule stress_series;
#                                         per group in the quick tier)
#   results/<study>/stress.csv            every case with its outcome (rule stress_report)
#   reports/<study>/stress.md             one row per case: claim, iterations, cond, true vs
#                                         recursive residual, error vs direct, PASS/FAIL
#   logs/<study>/cases/<series>.log, logs/<study>/stress_report.log

import re
import sys as _sys

STUDY = config["study"]

if workflow.basedir not in _sys.path:      # the repository's ddsolve, also without installing it
    _sys.path.insert(0, workflow.basedir)
from dataclasses import asdict as _asdict

from ddsolve.report.stress import catalog as _stress_catalog

STRESS_TIER = "quick" if STUDY == "stress_quick" else "study"
STRESS_CASES = _stress_catalog(STRESS_TIER)


def _stress_job(case):
    """The job of a case: its series; in the quick tier (a smoke test) its group, for fewer jobs."""
    return case.group if STRESS_TIER == "quick" else case.series

STRESS_SERIES = list(dict.fromkeys(_stress_job(case) for case in STRESS_CASES))


def stress_series_cases(wildcards):
    """The cases of one job as plain dicts (a params value: a changed case reruns its job)."""
    return [_asdict(case) for case in STRESS_CASES if _stress_job(case) == wildcards.series]


#: Wall-clock limit of one case (seconds); a case past it is recorded as a FAIL (timeout).
STRESS_CASE_TIMEOUT = 240


def report_files():
    """The stress study's targets (replaces the poisson/multibody reports of rule all)."""
    return [f"reports/{STUDY}/stress.md", f"results/{STUDY}/stress.csv"]


rule stress_series:
    output:
        f"results/{STUDY}/cases/{{series}}.json",
    params:
        cases=stress_series_cases,
        timeout=STRESS_CASE_TIMEOUT,
    wildcard_constraints:
        series="|".join(re.escape(s) for s in STRESS_SERIES),
    log:
        f"logs/{STUDY}/cases/{{series}}.log",
    threads: 1
    script:
        "../scripts/stress_series.py"


rule stress_report:
    input:
        expand(f"results/{STUDY}/cases/{{series}}.json", series=STRESS_SERIES),
    output:
        md=report(f"reports/{STUDY}/stress.md", caption="../report/stress.rst", category="Stress study"),
        csv=f"results/{STUDY}/stress.csv",
    log:
        f"logs/{STUDY}/stress_report.log",
    script:
        "../scripts/stress_report.py"
