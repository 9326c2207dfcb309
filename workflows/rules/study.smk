# One study: the rules of the config's `kind` (workflows/schemas/*.schema.yaml):
#   grid     a grid of poisson cases (config/poisson.yaml)
#   table_4  multibody cases, Tables 4.1/4.2 and the Section 4.4 figures (config/table_4.yaml)
#   contact  contact cases, Tables 5.1/6.1, the comparison, Figure 5.2 (config/table_5_6.yaml)
#   bench    the work-precision benchmark (config/bench.yaml)
#   scaling  the scaling study of the contact solvers (config/scaling.yaml)
#   stress   the numerical stability stress study (config/stress.yaml)
#   mpi      distributed solves with P MPI ranks (config/mpi.yaml; not in the reproduction)
#   ngsolve  DDInverse against NGSolve's solvers (config/ngsolve.yaml)
#   unstructured  DD against direct solvers on METIS-partitioned P1 meshes (config/unstructured.yaml)
# Its targets (rule all) are `targets()` of common.smk.
try:
    KIND = validate_study(config)
except studies_workflow.ConfigError as err:
    config_error(str(err))


include: "common.smk"


if KIND in GRID_KINDS:

    include: "solve.smk"
    include: "aggregate.smk"

    if KIND == "grid":

        include: "report.smk"

    elif KIND == "table_4":

        include: "multibody.smk"

    else:

        include: "contact.smk"

elif KIND == "bench":

    include: "bench.smk"

elif KIND == "scaling":

    include: "scaling.smk"

elif KIND == "mpi":

    include: "mpi.smk"
elif KIND == "ngsolve":

    include: "ngsolve.smk"
elif KIND == "unstructured":

    include: "unstructured.smk"

else:

    include: "stress.smk"
