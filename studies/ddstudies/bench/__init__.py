"""Work-precision benchmarks of the substructuring methods against peer solvers.

- :mod:`~ddstudies.bench.peers`: direct factorizations (MKL PARDISO, NGSolve,
  CHOLMOD, SuperLU) behind :func:`direct_solver`, and pyamg + CG
  (:func:`pyamg_cg`);
- :mod:`~ddstudies.bench.problems`: assembled benchmark problems
  (:data:`PROBLEMS`, :func:`build_problem`) with refinement-consistent loads;
- :mod:`~ddstudies.bench.refine`: the exact energy-norm total error against the
  2x refined solution;
- :mod:`~ddstudies.bench.methods`: the registry of benchmarked methods
  (:data:`METHODS`, :func:`register_method`);
- :mod:`~ddstudies.bench.case`: one measured case (:func:`run_case`) and the
  references (:func:`compute_reference`);
- :mod:`~ddstudies.bench.store`, :mod:`~ddstudies.bench.report`: files, summary
  table and the work-precision plot;
- :mod:`~ddstudies.bench.contact`: the contact problem (3.1) and its methods
  (``active-set``, ``smalbe``, the ``pdas`` peer), registered on import;
- :mod:`~ddstudies.bench.scaling`: the scaling study of the contact solvers
  (time against dofs, exponent fits, profile).

The Snakemake studies are ``workflows/rules/bench.smk`` with ``config/bench.yaml``
and ``workflows/rules/scaling.smk`` with ``config/scaling.yaml``.
"""
from __future__ import annotations

from . import contact  # noqa: F401  (registers problem "contact" and its methods)
from .case import CaseRecord, Reference, compute_reference, run_case
from .methods import METHODS, MethodRun, RunOptions, register_method
from .peers import DEFAULT_DIRECT, DIRECT_SOLVERS, BackendUnavailable, direct_solver, pyamg_cg
from .problems import PROBLEMS, BenchProblem, build_problem, register_problem

__all__ = [
    "BackendUnavailable", "BenchProblem", "CaseRecord", "DEFAULT_DIRECT", "DIRECT_SOLVERS", "METHODS",
    "MethodRun", "PROBLEMS", "Reference", "RunOptions", "build_problem", "compute_reference",
    "direct_solver", "pyamg_cg", "register_method", "register_problem", "run_case",
]
