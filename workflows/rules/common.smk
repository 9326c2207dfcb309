# Helpers shared by the rules: the case list and the parameters of one case.
# Paths depend only on a case's keys (study, method, subdomains, elements); all
# other parameters travel in `params`, so Snakemake's params rerun-trigger reruns
# exactly the cases whose parameters changed.
import re

STUDY = config["study"]

#: Config keys shared by every case, passed unchanged to ddsolve.spec.ProblemSpec.
SHARED_SPEC_KEYS = ("problem", "bodies", "rho", "f", "scaling", "gamma", "rtol", "maxiter", "cond", "check")

CASE = "{study}/{method}/Ns{subdomains}_m{elements}"


wildcard_constraints:
    study=re.escape(STUDY),
    method="|".join(re.escape(m) for m in config["methods"]),
    subdomains=r"[1-9]\d*",
    elements=r"[1-9]\d*",


def case_spec(wildcards):
    """The ProblemSpec mapping of one case (a plain dict: a params value)."""
    spec = {key: config[key] for key in SHARED_SPEC_KEYS if key in config}
    spec.update(method=wildcards.method, subdomains=int(wildcards.subdomains),
                elements=int(wildcards.elements))
    return spec


def case_files(wildcards=None):
    """All result files of the configured study."""
    return expand(f"results/{CASE}.h5", study=STUDY, method=config["methods"],
                  subdomains=config["subdomains"], elements=config["elements"])


def report_files():
    """The reports of the configured study (targets of rule all)."""
    return [f"reports/{STUDY}/table.md", f"reports/{STUDY}/table.tex",
            f"reports/{STUDY}/cond_vs_Hh.png"]
