# Helpers shared by the rules: the case list and the parameters of one case.
# Paths depend only on a case's keys (study, method, [contact, bodies,] subdomains,
# elements); all other parameters travel in `params`, so Snakemake's params
# rerun-trigger reruns exactly the cases whose parameters changed.
import itertools
import re

STUDY = config["study"]
MULTIBODY = config.get("problem", "poisson") == "multibody"
CONTACT = config.get("problem", "poisson") == "contact"

#: Config keys shared by every case, passed unchanged to ddsolve.spec.ProblemSpec
#: (a multibody case overrides `bodies` with its own value and adds `contact`).
SHARED_SPEC_KEYS = ("problem", "bodies", "rho", "f", "scaling", "gamma", "norm", "projection", "rtol", "maxiter",
                    "cond", "check")

#: One case's path below results/ and logs/ (without the suffix).
if MULTIBODY:
    CASE = "{study}/{method}/{contact}/Nb{bodies}_Ns{subdomains}_m{elements}"
else:
    CASE = "{study}/{method}/Ns{subdomains}_m{elements}"


def _as_list(value):
    return list(value) if isinstance(value, (list, tuple)) else [value]


def study_cases():
    """The (bodies, subdomains, elements) triples of the study, in config order, no duplicates.

    With `sweeps`: the union of the grids bodies x subdomains x elements of the
    sweeps, in the order listed; otherwise the one grid of the top-level keys.
    """
    sweeps = config.get("sweeps") or [
        {"bodies": config.get("bodies", 1), "subdomains": config["subdomains"],
         "elements": config["elements"]}]
    cases = {}
    for sweep in sweeps:
        grid = itertools.product(_as_list(sweep.get("bodies", config.get("bodies", 1))),
                                 _as_list(sweep["subdomains"]), _as_list(sweep["elements"]))
        cases.update(dict.fromkeys(tuple(int(v) for v in case) for case in grid))
    cases = list(cases)
    if CONTACT:  # two membranes, not a grid axis (the case paths have no bodies)
        cases = list(dict.fromkeys((1, s, m) for _, s, m in cases))
    elif not MULTIBODY and any(b != 1 for b, _, _ in cases):
        raise ValueError("config: problem 'poisson' has exactly one body; set problem: multibody "
                         "to sweep over bodies")
    return cases


CASES = study_cases()
CONTACTS = list(config.get("contacts", [])) if MULTIBODY else []


wildcard_constraints:
    study=re.escape(STUDY),
    method="|".join(re.escape(m) for m in config["methods"]),
    contact="|".join(re.escape(c) for c in CONTACTS) or "full",
    bodies=r"[1-9]\d*",
    subdomains=r"[1-9]\d*",
    elements=r"[1-9]\d*",


def case_spec(wildcards):
    """The ProblemSpec mapping of one case (a plain dict: a params value)."""
    spec = {key: config[key] for key in SHARED_SPEC_KEYS if key in config}
    spec.update(method=wildcards.method, subdomains=int(wildcards.subdomains),
                elements=int(wildcards.elements))
    if MULTIBODY:
        spec.update(bodies=int(wildcards.bodies), contact=wildcards.contact)
    else:
        spec["bodies"] = 2 if CONTACT else 1   # contact: the two membranes of (3.1)
    return spec


def case_files(wildcards=None):
    """All result files of the configured study."""
    contacts = CONTACTS or [None]
    return [f"results/{CASE}.h5".format(study=STUDY, method=method, contact=contact, bodies=b,
                                        subdomains=s, elements=m)
            for method in config["methods"] for contact in contacts for b, s, m in CASES]


# --- the multibody reports (thesis Section 4.4); rules in multibody.smk --------------

#: Thesis tables: the method they show, our quantities, the transcription compared with.
TABLES_4 = {
    "table_4_1": {"method": "feti-feti", "quantities": ["cond", "iterations"],
                  "title": "Table 4.1: FETI-FETI, condition number estimates and iterations"},
    "table_4_2": {"method": "hybrid", "quantities": ["iterations"],
                  "title": "Table 4.2: hybrid method, iterations"},
}
#: Figures: one parameter varied from the base case (the study's first case), cases I and
#: II, our values and the thesis's with a least-squares fit of `model`
#: (ddsolve.report.plots.FIT_MODELS).
FIGURES_4 = {
    "figure_4_2": {"method": "feti-feti", "x": "subdomains", "y": "cond", "model": "linear",
                   "logx": False, "thesis": "table_4_1",
                   "title": "FETI-FETI: condition number estimates against $H_b/H_s$"},
    "figure_4_3": {"method": "feti-feti", "x": "elements", "y": "cond",
                   "model": "log_squared_affine", "logx": True, "thesis": "table_4_1",
                   "title": "FETI-FETI: condition number estimates against $H_s/h$"},
    "figure_hybrid_iterations": {"method": "hybrid", "x": "elements", "y": "iterations",
                                 "model": "log_linear", "logx": True, "thesis": "table_4_2",
                                 "title": "Hybrid method: iterations against $H_s/h$"},
}


def thesis_table(name):
    """Path of a thesis transcription (config key thesis_tables)."""
    return f"{config['thesis_tables']}/{name}.csv"


def report_files():
    """The reports of the configured study (targets of rule all)."""
    if CONTACT:
        return contact_report_files()  # workflows/rules/contact.smk
    if not MULTIBODY:
        return [f"reports/{STUDY}/table.md", f"reports/{STUDY}/table.tex",
                f"reports/{STUDY}/cond_vs_Hh.png"]
    methods = set(config["methods"])
    files = []
    for name, table in TABLES_4.items():
        if table["method"] in methods:
            files += [f"reports/{STUDY}/{name}.md", f"reports/{STUDY}/{name}.tex"]
    files += [f"reports/{STUDY}/{name}.png" for name, fig in FIGURES_4.items() if fig["method"] in methods]
    return files
