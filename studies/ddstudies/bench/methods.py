"""The benchmarked methods: a registry of name -> runner.

A runner takes an assembled :class:`~ddstudies.bench.problems.BenchProblem`, a
relative tolerance (None for methods without one) and the
:class:`RunOptions`, and returns a :class:`MethodRun`. Everything the runner
does (operators, factorizations, iterations) counts as the method's time;
assembly of the problem does not. New methods, e.g. the contact solvers
(active set, SMALBE, PDAS with direct face solves) are added with
:func:`register_method` and named in the benchmark config.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ddsolve.dd import MethodOutput, solve_bddc, solve_feti, solve_fetidp

from .peers import DEFAULT_DIRECT, direct_solver, pyamg_cg
from .problems import BenchProblem


@dataclass(frozen=True)
class RunOptions:
    """Settings shared by all runs of a benchmark.

    Attributes
    ----------
    maxiter : int
        Iteration limit of the iterative methods.
    threads : int
        BLAS / solver threads.
    direct : str
        Backend of the ``direct`` peer and of the time baseline
        (:data:`ddstudies.bench.peers.DIRECT_SOLVERS`).
    """

    maxiter: int = 1000
    threads: int = 1
    direct: str = DEFAULT_DIRECT


@dataclass
class MethodRun:
    """What a runner returns.

    Attributes
    ----------
    u : ndarray, shape (ndof,)
        Approximate solution.
    converged : bool
    iterations : int
        Outer iterations (0 for direct solvers).
    extra : dict
        Scalars to record, e.g. ``setup_seconds`` (part of the run's time
        spent before the iteration).
    """

    u: np.ndarray
    converged: bool
    iterations: int
    extra: dict[str, Any] = field(default_factory=dict)


#: A runner: (problem, rtol or None, options) -> MethodRun.
Runner = Callable[[BenchProblem, "float | None", RunOptions], MethodRun]


@dataclass(frozen=True)
class Method:
    """A registered method.

    Attributes
    ----------
    run : Runner
    problems : tuple of str
        Problem kinds it solves (keys of :data:`ddstudies.bench.problems.PROBLEMS`).
    iterative : bool
        Takes a tolerance (run once per rtol of the study); otherwise run once.
    peer : bool
        A reference point from outside this project (drawn dashed).
    """

    run: Runner
    problems: tuple[str, ...]
    iterative: bool = True
    peer: bool = False


#: Registered methods: name -> Method.
METHODS: dict[str, Method] = {}


def register_method(name: str, run: Runner, *, problems: tuple[str, ...], iterative: bool = True,
                    peer: bool = False) -> None:
    """Add (or replace) a method of the benchmark."""
    METHODS[name] = Method(run=run, problems=tuple(problems), iterative=iterative, peer=peer)


def _from_output(out: MethodOutput) -> MethodRun:
    kr = out.krylov
    return MethodRun(u=out.u, converged=True if kr is None else bool(kr.converged),
                     iterations=0 if kr is None else int(kr.iterations),
                     extra={"setup_seconds": float(out.setup_seconds), "nlambda": int(out.nlambda),
                            "n_factorizations": int(out.n_factorizations)})


def _single_body(solver: Callable[..., MethodOutput]) -> Runner:
    def run(problem: BenchProblem, rtol: float | None, options: RunOptions) -> MethodRun:
        return _from_output(solver(problem.sub, rtol=rtol, maxiter=options.maxiter))
    return run


def _multibody(name: str) -> Runner:
    def run(problem: BenchProblem, rtol: float | None, options: RunOptions) -> MethodRun:
        gi, active = problem.context["gi"], problem.context["active"]
        if name == "feti-feti":
            from ddsolve.multibody.fetifeti import FetiFetiSolver
            solver = FetiFetiSolver(problem.sub, gi)
        else:
            from ddsolve.multibody.hybrid import HybridSolver
            solver = HybridSolver(problem.sub, gi)
        return _from_output(solver.solve(active, rtol=rtol, maxiter=options.maxiter))
    return run


def run_direct(problem: BenchProblem, rtol: float | None, options: RunOptions) -> MethodRun:
    """The direct peer: factor and solve the reduced system with ``options.direct``."""
    factor_seconds, solve = direct_solver(options.direct, problem.K, threads=options.threads)
    return MethodRun(u=problem.expand(solve(problem.rhs)), converged=True, iterations=0,
                     extra={"setup_seconds": factor_seconds})


def run_pyamg(problem: BenchProblem, rtol: float | None, options: RunOptions) -> MethodRun:
    """The AMG peer: pyamg smoothed aggregation + CG on the reduced system."""
    res = pyamg_cg(problem.K, problem.rhs, rtol if rtol is not None else 1e-8,
                   maxiter=options.maxiter, threads=options.threads)
    return MethodRun(u=problem.expand(res.x), converged=res.converged, iterations=res.iterations,
                     extra={"setup_seconds": res.setup_seconds})


register_method("feti", _single_body(solve_feti), problems=("poisson",))
register_method("fetidp", _single_body(solve_fetidp), problems=("poisson",))
register_method("bddc", _single_body(solve_bddc), problems=("poisson",))
register_method("feti-feti", _multibody("feti-feti"), problems=("multibody",))
register_method("hybrid", _multibody("hybrid"), problems=("multibody",))
register_method("direct", run_direct, problems=("poisson", "multibody"), iterative=False, peer=True)
register_method("pyamg", run_pyamg, problems=("poisson", "multibody"), peer=True)


def get_method(name: str, problem: str) -> Method:
    """The registered method ``name`` after checking that it solves ``problem``.

    Raises
    ------
    KeyError
        Unknown method, or one that does not solve this problem kind.
    """
    if name not in METHODS:
        raise KeyError(f"unknown benchmark method {name!r} (registered: {', '.join(METHODS)})")
    method = METHODS[name]
    if problem not in method.problems:
        raise KeyError(f"method {name!r} does not solve problem {problem!r} "
                       f"(it solves {', '.join(method.problems)})")
    return method
