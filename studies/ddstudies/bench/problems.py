"""Benchmark problems: an assembled problem, its reduced SPD system and its reference solve.

A :class:`BenchProblem` bundles what every benchmarked method needs: the
:class:`~ddsolve.dd.Substructures` of the scene, the assembled energy matrix
(for the energy-norm errors), the reduced SPD system ``K x = r`` with
``u = T x`` that the peer solvers factor, and problem-specific context. The
builders in :data:`PROBLEMS` make one from a :class:`~ddsolve.spec.ProblemSpec`;
a new problem kind is added with :func:`register_problem` (the contact
problem (3.1) is registered by :mod:`ddstudies.bench.contact`).

Loads are refinement-consistent: ``f = "random:SEED"`` is a piecewise constant
load, uniform in [-1, 1], on a grid of ``load_cells`` x ``load_cells`` cells of
the unit square (by default the element grid of the spec itself). The 2x
refined problem of the total-error reference is built with the coarse
``load_cells``, so that both discretize the same continuous problem.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

from ddsolve.dd import Substructures, solve_direct
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.direct import merge_matrix, solve_constrained_direct
from ddsolve.prepared import prepare, scene_from_spec
from ddsolve.scene import Scene
from ddsolve.spec import ProblemSpec, parse_f


@dataclass
class BenchProblem:
    """One assembled benchmark problem.

    Attributes
    ----------
    kind : str
        Key of :data:`PROBLEMS` that built it.
    spec : ProblemSpec
    sub : Substructures
    A : scipy.sparse.csr_matrix, shape (ndof, ndof)
        Assembled stiffness R^T diag(A^(i)) R (block diagonal over bodies):
        the energy norm of the errors.
    f : ndarray, shape (ndof,)
        Assembled load.
    K : scipy.sparse.csr_matrix
        Reduced SPD system matrix of the peer solvers (constraints eliminated).
    rhs : ndarray
        Its right-hand side.
    T : scipy.sparse.csr_matrix or None
        ``u = T x`` maps the reduced solution to the ndof vector (None: identity).
    reference : callable
        ``reference() -> u``, the project's own direct solve (the algebraic reference).
    context : dict
        Problem-specific objects, e.g. ``gi`` and ``active`` for multibody.
    load_cells : int or None
        Cells per side of the random load grid (None: the element grid, or a
        constant load).
    baseline : str
        Registered method whose time is the case's ``direct_seconds`` (the
        ``direct`` peer; ``pdas`` for contact).
    reference_vectors : callable or None
        ``reference_vectors() -> {name: ndarray}``: further vectors of the
        reference solve (called after ``reference()``), stored with the
        reference, e.g. the contact multipliers.
    case_errors : callable or None
        ``case_errors(problem, run, reference) -> {name: scalar}``: further
        error measures of a case (e.g. contact: l2 and multiplier errors).
    """

    kind: str
    spec: ProblemSpec
    sub: Substructures
    A: sp.csr_matrix
    f: np.ndarray
    K: sp.csr_matrix
    rhs: np.ndarray
    T: sp.csr_matrix | None
    reference: Callable[[], np.ndarray]
    context: dict[str, Any] = field(default_factory=dict)
    load_cells: int | None = None
    baseline: str = "direct"
    reference_vectors: Callable[[], dict[str, np.ndarray]] | None = None
    case_errors: Callable[..., dict[str, Any]] | None = None

    @property
    def ndof(self) -> int:
        """Global (Dirichlet-free) degrees of freedom."""
        return self.sub.ndof

    def expand(self, x: np.ndarray) -> np.ndarray:
        """``T x``: a reduced solution as an ndof vector."""
        return x if self.T is None else self.T @ x


#: A problem builder: (spec, load_cells) -> BenchProblem.
ProblemBuilder = Callable[[ProblemSpec, "int | None"], BenchProblem]

#: Problem kinds: name -> builder.
PROBLEMS: dict[str, ProblemBuilder] = {}


def register_problem(name: str, builder: ProblemBuilder) -> None:
    """Add (or replace) a problem kind of the benchmark."""
    PROBLEMS[name] = builder


def cell_loads(scene: Scene, cells: int, seed: int) -> np.ndarray:
    """Element loads of a piecewise constant random field on a cells x cells grid.

    Parameters
    ----------
    scene : Scene
        Any mesh of the unit square (the field does not depend on it).
    cells : int
        Cells per side of the grid on which the field is constant.
    seed : int
        Seed of numpy's default generator; cell values are uniform in [-1, 1].

    Returns
    -------
    ndarray, shape (n_elements,)
        The value of the cell containing each element's centroid.
    """
    values = np.random.default_rng(int(seed)).uniform(-1.0, 1.0, (cells, cells))
    centroid = scene.coords[scene.elements].mean(axis=1)
    ij = np.clip(np.floor(centroid * cells).astype(np.int64), 0, cells - 1)
    return values[ij[:, 1], ij[:, 0]]


def check_load_cells(spec: ProblemSpec, load_cells: int | None) -> None:
    """Refuse a load grid that the mesh of ``spec`` does not resolve.

    The cells must tile the element grid (``bodies * subdomains * elements``
    elements per side a multiple of ``load_cells``): then every element, of
    this mesh and of its refinements, lies in one cell, and the coarse and
    refined problems discretize the same load.

    Raises
    ------
    ValueError
        ``load_cells: ...`` naming the element grid, or a load that is not ``random:SEED``.
    """
    if load_cells is None:
        return
    if parse_f(spec.f)[0] != "random":
        raise ValueError(f"load_cells: {load_cells} applies to a random:SEED load only, not f={spec.f!r}")
    side = spec.bodies * spec.subdomains * spec.elements
    if load_cells > side or side % load_cells:
        raise ValueError(f"load_cells: {load_cells} must divide the {side} elements per side "
                         f"(bodies * subdomains * elements), so that each element lies in one load cell")


def bench_scene(spec: ProblemSpec, load_cells: int | None = None) -> Scene:
    """The structured scene of ``spec`` with a refinement-consistent load.

    Parameters
    ----------
    spec : ProblemSpec
    load_cells : int, optional
        Cells per side of the random load grid; default: the elements per
        side of this mesh, bodies * subdomains * elements.
    """
    check_load_cells(spec, load_cells)
    scene = scene_from_spec(spec)
    kind, value = parse_f(spec.f)
    if kind == "random":
        cells = load_cells or spec.bodies * spec.subdomains * spec.elements
        scene.f = cell_loads(scene, cells, int(value))
    return scene


def _substructures(spec: ProblemSpec, load_cells: int | None) -> Substructures:
    return prepare(spec, scene=bench_scene(spec, load_cells)).sub


def poisson_problem(spec: ProblemSpec, load_cells: int | None = None) -> BenchProblem:
    """-div(rho grad u) = f on the unit square, u = 0 on its boundary."""
    sub = _substructures(spec, load_cells)
    A = sub.global_matrix()
    f = sub.assemble_vector(sub.f_W)
    return BenchProblem(kind="poisson", spec=spec, sub=sub, A=A, f=f, K=A, rhs=f, T=None,
                        reference=lambda: solve_direct(sub).u)


def multibody_problem(spec: ProblemSpec, load_cells: int | None = None) -> BenchProblem:
    """Problem (4.32): bodies tied on the active contact area ``spec.contact``.

    The reduced system merges the dofs tied by active constraints
    (:func:`ddsolve.multibody.direct.merge_matrix`): K = T^T A T, r = T^T f.
    """
    sub = _substructures(spec, load_cells)
    gi = GlobalInterface(sub)
    active = gi.contact_mask(spec.contact)
    A = sub.global_matrix()
    f = sub.assemble_vector(sub.f_W)
    T = merge_matrix(sub, gi, active)
    K = (T.T @ A @ T).tocsr()
    return BenchProblem(kind="multibody", spec=spec, sub=sub, A=A, f=f, K=K, rhs=T.T @ f, T=T,
                        reference=lambda: solve_constrained_direct(sub, gi, active).u,
                        context={"gi": gi, "active": active})


register_problem("poisson", poisson_problem)
register_problem("multibody", multibody_problem)


def build_problem(spec: ProblemSpec | dict[str, Any], load_cells: int | None = None) -> BenchProblem:
    """Build the benchmark problem of ``spec`` (kind ``spec.problem``).

    Parameters
    ----------
    spec : ProblemSpec or mapping
    load_cells : int, optional
        Cells per side of the grid of a ``random:SEED`` load (see :func:`cell_loads`);
        default: the element grid of the mesh.

    Raises
    ------
    KeyError
        No builder is registered for ``spec.problem``.
    """
    if not isinstance(spec, ProblemSpec):
        spec = ProblemSpec.from_mapping(spec)
    if spec.problem not in PROBLEMS:
        raise KeyError(f"no benchmark problem {spec.problem!r} (registered: {', '.join(PROBLEMS)})")
    problem = PROBLEMS[spec.problem](spec, load_cells)
    if parse_f(spec.f)[0] == "random":
        problem.load_cells = int(load_cells or spec.bodies * spec.subdomains * spec.elements)
    return problem
