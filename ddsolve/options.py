"""The option lists of ddsolve: one numpy-free module read by the spec, the solvers and the workflow schemas.

Every list of accepted values lives here once. :mod:`ddsolve.spec` validates
against it, the solvers import it, and the Snakemake workflow injects it into
its JSON schemas (``workflows/rules/common.smk``), so that a new option is added
in one place. The module imports nothing beyond the standard library.
"""
from __future__ import annotations

#: Problems and the methods each one accepts (the first is the default).
METHODS: dict[str, tuple[str, ...]] = {
    "poisson": ("fetidp", "feti", "bddc", "direct"),
    "multibody": ("feti-feti", "hybrid", "direct"),
    "contact": ("active-set", "smalbe", "direct"),
}
#: Default right-hand side per problem: f = 1 for poisson; a generic seeded load for
#: multibody (f = 1 is symmetric there and PCG converges unrepresentatively fast).
DEFAULT_F: dict[str, float | str] = {"poisson": 1.0, "multibody": "random:0", "contact": "dostal"}
#: Default relative tolerance per problem (contact: the 1e-5 of Chapters 5 and 6).
DEFAULT_RTOL: dict[str, float] = {"contact": 1e-5}
#: Active contact areas between the bodies of problem (4.32): case (I) and case (II).
CONTACTS: tuple[str, ...] = ("full", "middle")
#: Scalings of the jump operator B_D (Section 2.3).
SCALINGS: tuple[str, ...] = ("rho", "multiplicity")
#: Stopping norms of PCR: Euclidean, or <r, M r>^(1/2) with M the preconditioner.
NORMS: tuple[str, ...] = ("l2", "M")
#: Projections onto V^k = ker(G^kT) of the hybrid method.
PROJECTIONS: tuple[str, ...] = ("orthogonal", "dirichlet", "lumped")
#: Methods that take ``norm`` and ``projection`` other than the defaults.
PCR_METHODS: tuple[str, ...] = ("hybrid",)
#: Rule sets (:mod:`ddsolve.presets`): ``"default"`` (the project's improved rules) or ``"thesis"``
#: (the thesis's rules as printed, wherever the defaults differ; docs/methods.md, "The thesis preset").
PRESETS: tuple[str, ...] = ("default", "thesis")
#: Meshes: the structured Q1 squares of the thesis, or netgen P1 triangles split by METIS.
MESHES: tuple[str, ...] = ("structured", "unstructured")
#: Built-in unstructured geometries of each problem (the first is the default; ddsolve.scene.unstructured).
GEOMETRIES: dict[str, tuple[str, ...]] = {"poisson": ("square", "lshape", "hole"), "multibody": ("square",),
                                          "contact": ("membranes",)}
#: Primal (coarse) constraints of FETI-DP/BDDC: subdomain vertices, or vertices and edge averages.
PRIMALS: tuple[str, ...] = ("vertices", "vertices+edges")
#: Methods that take ``primal`` other than the default.
PRIMAL_METHODS: tuple[str, ...] = ("fetidp", "bddc")
#: All method names, in a stable order.
ALL_METHODS: tuple[str, ...] = tuple(dict.fromkeys(m for ms in METHODS.values() for m in ms))

__all__ = ["METHODS", "DEFAULT_F", "DEFAULT_RTOL", "CONTACTS", "SCALINGS", "NORMS", "PROJECTIONS",
           "PCR_METHODS", "PRESETS", "ALL_METHODS",
           "MESHES", "GEOMETRIES", "PRIMALS", "PRIMAL_METHODS"]
