"""DDInverse: BDDC / FETI-DP / FETI as an inverse or preconditioner of an NGSolve BilinearForm."""
from __future__ import annotations

import logging
import time
import warnings
from typing import Any

import ngsolve
import numpy as np

from ..dd import Substructures
from ..dd.check import energy_error_estimate
from ..dd.edges import subdomain_edges_3d
from ..errors import ConvergenceWarning, InputError, check_flag, check_seed, check_tolerance
from ..krylov.convergence import ERROR_CAP, ERROR_FACTOR, ERROR_FLOOR, error_limit
from ..options import PRIMAL_METHODS, PRIMALS
from .dofs import (
    active_elements,
    add_boundary_matrices,
    boundary_element_matrices,
    check_space,
    element_dofs,
    element_matrices,
    is_symmetric,
    node_vertices,
    split_integrators,
    uncompressed,
    vertex_table,
)
from .consistency import check_boundary_terms, check_finite, check_linear
from .facets import facet_adjacency
from .local import (
    condense,
    element_parts,
    interface_edge_weights,
    ordering_anchors,
    part_matrices,
)
from .methods import _BDDC, _FETI, _FETIDP
from .pieces import check_not_singular, mesh_pieces

log = logging.getLogger(__name__)

METHODS = ("bddc", "fetidp", "feti")
SCALINGS = ("diagonal", "rho", "multiplicity", "deluxe")
#: METIS parts when neither ``parts`` nor a partition that gives them is set.
DEFAULT_PARTS = 16
#: Weighted (integral) edge averages at order 1 too (at order >= 2 always; see ddsolve.dd.edges).
#: Off: at order 1 the integral and the nodal mean gave condition numbers within 1.3 % of each
#: other (docs/ngsolve.md), and the nodal one costs no extra assembly.
EDGE_WEIGHTS_P1 = False


def _free_mask(fes: Any, freedofs: Any) -> np.ndarray:
    if freedofs is None:
        freedofs = fes.FreeDofs()
    try:
        raw = np.asarray(freedofs) if not isinstance(freedofs, ngsolve.BitArray) else None
        free = np.array(freedofs, dtype=bool)
    except (TypeError, ValueError) as exc:
        raise InputError("freedofs", f"expected a BitArray or boolean array ({exc})") from None
    if free.shape != (fes.ndof,):
        raise InputError("freedofs", f"expected {fes.ndof} entries, got shape {free.shape}")
    # a numeric array must hold 0/1 flags: 0.5 or NaN was read as free (bool(x) of any nonzero)
    if raw is not None and raw.dtype != bool and not (raw.dtype.kind in "iuf" and np.isin(raw, (0, 1)).all()):
        got = (f"values such as {raw[~np.isin(raw, (0, 1))][0]}" if raw.dtype.kind in "iuf"
               else f"an array of dtype {raw.dtype}")
        raise InputError("freedofs", f"expected booleans or 0/1 entries, got {got}")
    return free


def _check_vector(name: str, v: np.ndarray, ndof: int) -> np.ndarray:
    """``v`` as an array of shape (ndof,), else an InputError naming ``name``."""
    v = np.asarray(v)
    if v.shape != (ndof,):
        raise InputError(name, f"expected a vector of {ndof} entries (the space's ndof), got shape {v.shape}")
    if np.iscomplexobj(v):
        raise InputError(name, "complex vectors are not supported (the form and its space are real)")
    return v


def _check_same_dofs(fes: Any, form_space: Any, dofs: np.ndarray | None, elements: np.ndarray | None,
                     T: np.ndarray) -> None:
    """Refuse a ``fes`` that numbers the dofs otherwise than the form's space (another ``definedon=``,
    ``Periodic`` or ``Compress``): equal ndof does not make the same system (a review: a periodic ``fes``
    for a non-periodic form, or the reverse, was solved and reported converged, 44% off).

    ``dofs``, ``elements``, ``T``: :func:`uncompressed`'s map, :func:`active_elements` and the element
    table of ``fes``. The form's space gets the same three and must agree (one more table: only when a
    separate ``fes`` is given).
    """
    space, other_dofs = uncompressed(form_space)
    other_elements = active_elements(space)

    def same(x: np.ndarray | None, y: np.ndarray | None) -> bool:
        return (x is None and y is None) or (x is not None and y is not None and np.array_equal(x, y))

    if (type(uncompressed(fes)[0]) is not type(space) or not same(dofs, other_dofs)
            or not same(elements, other_elements) or not np.array_equal(T, element_dofs(space, other_elements))):
        raise InputError("fes", "numbers the dofs otherwise than the form's space (another definedon=, Periodic or "
                                "Compress, or another order); give a space that differs in dirichlet= only, or None")


class DDInverse(ngsolve.BaseMatrix):
    """Substructuring inverse of an NGSolve BilinearForm on a scalar H1 space (any order).

    ``gfu.vec.data = DDInverse(a) * f.vec`` solves A u = f on the free dofs
    (zero on the others), like ``a.mat.Inverse(fes.FreeDofs())``. The mesh is
    2D (triangles or quadrilaterals) or 3D (tetrahedra or hexahedra). In 3D the primal dofs
    are those shared by three or more parts (the nodes of the subdomain edges
    and vertices, at every order) and the vertex dofs shared by two parts on the
    domain boundary: a vertex-only coarse space would not be scalable in 3D.

    Parameters
    ----------
    a : ngsolve.BilinearForm
        Assembled or not: its volume integrators are assembled once on
        ``Discontinuous(fes)``, its boundary (``ds``) integrators element by
        element on the boundary and added to the volume element they bound.
    fes : ngsolve.H1, optional
        Defaults to ``a.space``; else a space with the same dofs (same mesh and
        order, e.g. other ``dirichlet=`` boundaries, whose ``FreeDofs()`` are used).
        A scalar H1 space, also with ``definedon=`` (only its materials' elements
        enter), ``ngsolve.Compress(H1(...))`` (the dropped dofs fixed at zero) or
        ``ngsolve.Periodic(H1(...))``.
    method : {"bddc", "fetidp", "feti"}
    parts : int, optional
        METIS parts (default 16) for ``partition`` None or "coarse". With "materials" or an array the
        partition gives the parts, and ``parts`` must be left unset (an ``InputError`` otherwise: it was
        ignored silently; a review).
    partition : None, "coarse", "materials" or array of int, shape (mesh.ne,)
        None: METIS on the mesh; "coarse": METIS on the coarsest mesh of a
        ``mesh.Refine()`` hierarchy, children inherit the part; "materials":
        one part per material; an array: the part of every element (with
        ``definedon=``, only the labels of the space's elements are used).
    primal : {"vertices", "vertices+edges"}
        Primal constraints; edge averages for bddc and fetidp only. 2D: "vertices" are the
        dofs shared by three or more parts (or two on the boundary); at order >= 2 an
        edge average is the mean of u along the edge, sum_j w_j u_j / sum_j w_j with
        w_j the integral of the shape j along it
        (:func:`~ddsolve.ngsolve.local.interface_edge_weights`); at order 1 the mean of
        the nodal values (the same condition numbers within about 1 %, no extra assembly).
        3D: "vertices" makes every dof shared by three or more parts primal (all of the
        subdomain edges); "vertices+edges" is the thesis's 3D space (Section 2.6, (2.22)):
        the subdomain vertices and one average per subdomain edge
        (:func:`~ddsolve.dd.edges.subdomain_edges_3d`; at order >= 2 the mean of the
        edge's vertex values), a coarse problem about a third as large, but not robust
        for coefficient jumps inside the parts (docs/ngsolve.md, "3D meshes").
    rtol, maxiter : float, int
        Krylov stopping rule ||r_k|| <= rtol ||r_0|| on the interface / dual problem.
    freedofs : BitArray or array of bool, optional
        Defaults to ``fes.FreeDofs()``. A form built with ``condense=True`` (NGSolve's static
        condensation: ``a.mat`` is the Schur complement on the coupling dofs) is inverted as
        ``a.mat.Inverse(fes.FreeDofs(True))`` is: the cell-interior (``LOCAL_DOF``) dofs count as
        free and are eliminated inside, their loads are read as zero and their values returned as
        zero, so ``DDInverse`` drops into NGSolve's condensation recipe (``harmonic_extension_trans``,
        the inverse, ``harmonic_extension``, ``inner_solve``).
    cond : bool
        Lanczos condition-number estimate of the preconditioned operator.
    scaling : {"diagonal", "rho", "multiplicity", "deluxe"}
        delta-dagger weights: per dof proportional to the diagonal of each
        subdomain matrix (default), per part by the part's mean diagonal
        (rho-scaling of Section 2.3), or 1/multiplicity; "deluxe" (bddc and
        fetidp): dense face weights (S_i^F + S_j^F)^{-1} S_i^F from the local
        Schur complements (:mod:`ddsolve.dd.deluxe`), for coefficients that jump
        inside the parts (it forms the explicit local Schur complements, which
        does not pay for a smooth coefficient; docs/ngsolve.md).
    seed : int
        METIS seed.

    Attributes
    ----------
    iterations, cond, converged, reason : last solve's Krylov data. A solve that does not
        converge also issues a :class:`~ddsolve.errors.ConvergenceWarning`.
    residuals : ndarray
        The last solve's Krylov residual norms ||r_k||, absolute, of the interface (bddc) or
        dual (fetidp, feti) problem, one per iteration from r_0.
    relative_residual : float
        ||f - A u|| / ||f|| of the last solve, from the subdomain matrices (one product).
    scaled_residual : float
        ||D^{-1/2} (f - A u)|| / ||D^{-1/2} f|| of the last solve, D = diag(A): the relative
        residual of the Jacobi-scaled equations, which a coefficient jump does not inflate.
    error_estimate : float
        sqrt(r^T M^{-1} r / f^T u) of the last solve (M^{-1}: one BDDC application): an upper
        bound of the relative energy error ||u - u*||_A / ||u||_A, above it by at most sqrt(cond).
        The solve is reported not converged when it exceeds :attr:`error_limit`, whatever the
        Krylov rule said.
    error_limit : float
        max(min(100 rtol, 0.1), 1e-9).
    ndof : int
        The space's number of dofs when the inverse was built (see :meth:`Update`).
    timings : dict
        Seconds per phase (dof_table, assembly, partition, condense, substructures, setup, solve).
    n_parts : int
        Number of subdomains (after splitting parts that are not connected).
    elements : ndarray of int or None
        The mesh numbers of the elements with dofs (a space with ``definedon=``); None: all.
    """

    def __init__(self, a: Any, fes: Any = None, *, method: str = "bddc", parts: int | None = None, partition: Any = None,
                 primal: str = "vertices", rtol: float = 1e-8, maxiter: int = 1000, freedofs: Any = None,
                 cond: bool = False, scaling: str = "diagonal", seed: int = 0) -> None:
        super().__init__()
        if not isinstance(a, ngsolve.BilinearForm):
            raise InputError("a", f"expected an ngsolve.BilinearForm, got {type(a).__name__}")
        flags = a.flags.ToDict()
        if flags.get("diagonal"):       # NGSolve keeps only the diagonal of each element matrix then
            raise InputError("a", "a form with diagonal=True is not supported: its a.mat is the diagonal of the "
                                  "element matrices; invert it directly (a.mat.Inverse(freedofs))")
        if a.testspace is not a.trialspace:  # BilinearForm(trialspace=..., testspace=...): not an operator on one space
            raise InputError("a", "its trial and test spaces differ (BilinearForm(trialspace=, testspace=)); "
                                  "DDInverse inverts a form on one space")
        fes = a.space if fes is None else fes
        check_space(uncompressed(fes)[0])
        if fes.mesh.ne == 0:
            raise InputError("mesh", f"has no {fes.mesh.dim}D (volume) elements (a surface mesh?); DDInverse "
                                     "needs a mesh of triangles or quadrilaterals (2D) or tetrahedra or hexahedra (3D)")
        if not fes.mesh == a.space.mesh:
            raise InputError("fes", "is on another mesh than the form's space; give a space on the form's mesh or None")
        if method not in METHODS:
            raise InputError("method", f"expected one of {METHODS}, got {method!r}")
        if scaling not in SCALINGS:
            raise InputError("scaling", f"expected one of {SCALINGS}, got {scaling!r}")
        if primal not in PRIMALS:
            raise InputError("primal", f"expected one of {PRIMALS}, got {primal!r}")
        if primal != "vertices" and method not in PRIMAL_METHODS:
            raise InputError("primal", f"{primal!r} needs method 'bddc' or 'fetidp'; method {method!r} has "
                                       "'vertices' only")
        rtol, cond = check_tolerance("rtol", rtol), check_flag("cond", cond)
        if isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer)) or maxiter < 1:
            raise InputError("maxiter", f"must be a positive integer, got {maxiter!r}")
        seed = check_seed("seed", seed)
        # "materials" or an array only: a mistyped name is left to the partition's own check (a review)
        if parts is not None and (partition == "materials" if isinstance(partition, str) else partition is not None):
            given = f"{partition!r}" if isinstance(partition, str) else "an array"
            raise InputError("parts", f"is given by partition={given}; leave parts unset (it counts METIS parts "
                                      "only, for partition None or 'coarse')")
        parts = DEFAULT_PARTS if parts is None else parts
        if scaling == "deluxe" and method == "feti":
            raise InputError("scaling", "'deluxe' needs method 'bddc' or 'fetidp'")
        self.a, self.fes, self.method, self.rtol, self.maxiter = a, fes, method, rtol, int(maxiter)
        self.want_cond, self.scaling, self.primal = bool(cond), scaling, primal
        self._freedofs, self._parts, self._partition, self._seed = freedofs, parts, partition, seed
        self._setup()

    def Update(self) -> None:
        """Rebuild from the form's current integrators and the space's current dofs.

        A ``DDInverse`` is a snapshot, like ``a.mat.Inverse()``: it keeps the element matrices of
        the form as they were when it was built. Call ``Update()`` after changing a coefficient (a
        ``Parameter``, a ``GridFunction``), or after ``mesh.Refine()`` and ``fes.Update()``; the
        constructor's arguments are kept (a ``partition`` array must still fit the mesh).
        """
        self._setup()

    def _setup(self) -> None:
        """Validate the form and the space as they are now, then partition, condense and factorize."""
        a, fes, method, primal, scaling = self.a, self.fes, self.method, self.primal, self.scaling
        freedofs, parts, partition, seed = self._freedofs, self._parts, self._partition, self._seed
        if fes.ndof != a.space.ndof:        # another order or mesh: the inverse would not be one of a.mat
            raise InputError("fes", f"has {fes.ndof} dofs but the form's space has {a.space.ndof}; give a space "
                                    "of the form's order on the form's mesh (e.g. other dirichlet=) or None")
        dim = int(fes.mesh.dim)
        self.timings: dict[str, float] = {}
        self.iterations = 0
        self.residuals = np.zeros(0)
        self.cond: float | None = None
        self.converged: bool | None = None
        self.reason = ""
        self.relative_residual: float | None = None
        self.scaled_residual: float | None = None
        self.error_estimate: float | None = None
        free = _free_mask(fes, freedofs)
        # the dofs whose loads a solve reads and whose values it returns: the free ones, except for a form
        # with condense=True, whose a.mat is NGSolve's Schur complement on the coupling dofs; DDInverse
        # then inverts that (as a.mat.Inverse(fes.FreeDofs(True))): the cell-interior (LOCAL_DOF) dofs are
        # free inside and eliminated, their loads read as zero and their values returned as zero
        io_free = free
        if a.condense:
            local = np.array(fes.FreeDofs(False), dtype=bool) & ~np.array(fes.FreeDofs(True), dtype=bool)
            free = free | local
            io_free = free & ~local
        self.ndof = fes.ndof
        # ngsolve.Compress(space): the solve works on the space under it, whose dofs self._dofs the
        # compressed one numbers; the others are not free (their loads and values are not the user's)
        space, self._dofs = uncompressed(fes)
        ndof = self._n_space = space.ndof
        self.free, self.io_free = self._to_space(free), self._to_space(io_free)
        fes = space

        t = time.perf_counter()
        # the elements with dofs: all, or those of the regions of a space with definedon= (its other
        # elements, their vertex dofs unused and never free, are not part of the problem)
        elements = self.elements = active_elements(fes)
        V = vertex_table(fes.mesh)
        if elements is not None:
            V = V[elements]
        T = element_dofs(fes, elements)
        if self.fes is not a.space:
            _check_same_dofs(self.fes, a.space, self._dofs, elements, T)
        self.timings["dof_table"] = time.perf_counter() - t
        t = time.perf_counter()
        volume, boundary = split_integrators(a, fes)
        check_linear(a, fes, boundary)
        Ke = element_matrices(a, fes, T.shape[1], volume, n_elements=T.shape[0])
        check_finite(Ke, "dx")
        bnd = boundary_element_matrices(fes, boundary)   # ds terms (Robin): added to the element they bound
        if bnd is not None:
            check_finite(bnd[0], "ds")
            check_boundary_terms(fes, boundary, *bnd[:2])
            add_boundary_matrices(Ke, T, V, *bnd, dim=dim)
        self.timings["assembly"] = time.perf_counter() - t
        if not is_symmetric(Ke):
            raise InputError("a", f"the form is not symmetric; method {method!r} needs a symmetric form")
        t = time.perf_counter()
        graph, boundary = facet_adjacency(V, dim, ndof)     # facet graph, boundary vertex dofs (= vertex numbers)
        part = element_parts(fes.mesh, V, parts, partition, seed=seed, graph=graph, elements=elements)
        # pieces joined by facets, then by shared vertex dofs (a corner where two pieces touch; the two
        # sides of a periodic identification)
        n_pieces, piece_of_part = mesh_pieces(part, graph, T[:, :V.shape[1]], isinstance(fes, ngsolve.comp.Periodic))
        self.timings["partition"] = time.perf_counter() - t
        check_not_singular(Ke, T, self.free, fes.mesh.nv, part, n_pieces, piece_of_part)   # after the partition's checks
        t = time.perf_counter()
        self.cond_data = condense(Ke, T, self.free)
        del Ke
        c = self.cond_data
        self.T_w, self.T_b = T[:, c.w], T[:, c.b]
        self.timings["condense"] = time.perf_counter() - t

        t = time.perf_counter()
        pm = part_matrices(c.S, self.T_w, part, self.free, ndof, boundary)
        if n_pieces > 1:     # disjoint pieces of the mesh are bodies: no primal node joins one to another
            pm.local.scene.n_bodies, pm.local.scene.subdomain_body = n_pieces, piece_of_part.astype(np.int64)
        self.n_parts = pm.n_parts
        sub = Substructures(pm.local, scaling="multiplicity" if scaling == "multiplicity" else "rho",
                            templates=False, primal=primal)
        # the nested dissection of the subdomain factorizations runs on the mesh vertices (ddsolve.dd.local):
        # 2D, and 3D at order 2 (edge dofs only). With the face dofs of 3D order >= 3 it gave 31-34% more
        # fill (docs/ngsolve.md, "Cheaper setup")
        if fes.globalorder >= 2 and (dim == 2 or fes.globalorder == 2):
            sub.ordering_anchors = ordering_anchors(sub, pm.node_dof, node_vertices(T, fes.globalorder, dim, ndof))
        if scaling in ("diagonal", "deluxe"):      # deluxe: the diagonal weights off the faces
            d = sub.K_W.diagonal()
            total = np.bincount(sub.node_of_W, weights=d, minlength=sub.scene.n_nodes)
            with np.errstate(divide="ignore", invalid="ignore"):   # a zero diagonal: refused below, not warned
                sub.delta = d / total[sub.node_of_W]
        if primal == "vertices+edges" and dim == 3:
            # the thesis's 3D primal space (Section 2.6, (2.22)): vertex values and edge averages
            sub.vertex, sub.edge_candidates = subdomain_edges_3d(sub)
            if fes.globalorder >= 2:      # the average of the vertex values (the linear interpolant's nodal mean)
                sub.edge_weights = (pm.node_dof < fes.mesh.nv).astype(float)
        elif primal == "vertices+edges" and (fes.globalorder >= 2 or EDGE_WEIGHTS_P1):
            sub.edge_weights = interface_edge_weights(fes, part, V, T, elements)[pm.node_dof]
        self.sub = sub
        self.space = sub.primal_space()         # primal "vertices+edges": the edge-average basis (ddsolve.dd.edges)
        # global dof (of ddsolve: free nodes) -> H1 dof
        free_nodes = np.flatnonzero(~pm.local.scene.dirichlet)
        self.h1_of_gdof = pm.node_dof[free_nodes]
        diag = np.bincount(sub.l2g, weights=sub.K_W.diagonal(), minlength=free_nodes.size)    # D of the scaled residual
        self._inv_sqrt_diag = 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0))
        self.timings["substructures"] = time.perf_counter() - t

        t = time.perf_counter()
        try:
            self._build_operators(method, sub, pm, fes)
        except (np.linalg.LinAlgError, RuntimeError) as exc:
            # dense Cholesky (LinAlgError) or PARDISO (RuntimeError, error -4) of a subdomain matrix
            if isinstance(exc, RuntimeError) and "not positive definite" not in str(exc):
                raise
            if method == "feti":       # FETI factors the floating parts' matrices without constraints
                raise InputError("a", "a subdomain matrix is not positive definite: FETI needs SPD floating parts "
                                      "(negative reaction?); bddc and fetidp constrain their vertices") from None
            raise InputError("a", "a subdomain matrix is not positive definite; DDInverse needs element matrices "
                                  "that sum to SPD subdomain matrices (no negative reaction term, no Helmholtz form, "
                                  "no first-order term even where the global matrix is SPD)") from None
        self.timings["setup"] = time.perf_counter() - t
        log.info("DDInverse: %d parts, %d dofs, %d primal, timings %s", self.n_parts, ndof, sub.n_primal,
                 self.timings)

    def _build_operators(self, method: str, sub: Substructures, pm: Any, fes: Any) -> None:
        """Factor the subdomain matrices once: the BDDC operators, and FETI-DP's or FETI's."""
        self._bddc = _BDDC(self.space.sub, deluxe=self.scaling == "deluxe")
        self._fetidp = _FETIDP(self.space.sub, self._bddc) if method == "fetidp" else None
        self._feti: _FETI | None = None
        if method == "feti":
            # the constants are 1 on the vertex dofs and 0 on the edge/bubble dofs of a hierarchical basis;
            # a part floats when it has a free vertex dof and its matrix annihilates them (no fixed vertex
            # dof, no reaction or Robin term; fixed edge or bubble dofs leave the constants in the kernel)
            vertex_W = pm.node_dof[sub.node_of_W] < fes.mesh.nv
            R1 = sub.K_W @ vertex_W.astype(float)
            res = np.bincount(sub.sub_of_W, weights=np.abs(R1), minlength=sub.n_sub)
            scale = np.bincount(sub.sub_of_W, weights=np.abs(sub.K_W.diagonal()), minlength=sub.n_sub)
            has_vertex = np.bincount(sub.sub_of_W, weights=vertex_W, minlength=sub.n_sub) > 0
            sub.floating_sub = has_vertex & (res <= 1e-10 * scale)
            self._feti = _FETI(sub, self._bddc, vertex_W)

    # ----------------------------------------------------------- BaseMatrix
    def Height(self) -> int:
        return self.ndof

    def Width(self) -> int:
        return self.ndof

    def IsComplex(self) -> bool:
        return False

    def CreateColVector(self):
        return ngsolve.BaseVector(self.ndof, False)

    def CreateRowVector(self):
        return ngsolve.BaseVector(self.ndof, False)

    def CreateVector(self, colvector: bool = False):
        return ngsolve.BaseVector(self.ndof, False)

    def _to_space(self, x: np.ndarray) -> np.ndarray:
        """A vector (or mask) of the user's space, shape (ndof,), on the solver's space (zero elsewhere)."""
        if self._dofs is None:
            return x
        out = np.zeros(self._n_space, dtype=x.dtype)
        out[self._dofs] = x
        return out

    def _from_space(self, u: np.ndarray) -> np.ndarray:
        """The user's entries, shape (ndof,), of a vector of the solver's space."""
        return u if self._dofs is None else u[self._dofs]

    def _check_unchanged(self) -> None:
        """Refuse a space whose dofs changed since the build (mesh.Refine() and fes.Update())."""
        if self.fes.ndof != self.ndof:
            raise InputError("fes", f"has {self.fes.ndof} dofs now, {self.ndof} when this DDInverse was built "
                                    "(mesh.Refine() and fes.Update()?); call Update() or build a new DDInverse")

    def Mult(self, x: Any, y: Any) -> None:
        self._check_unchanged()
        # the right-hand side first, by the name of solve(f): for a complex f, NGSolve's result vector is
        # complex too, and the error named "y", a vector the user never wrote (a review)
        f = _check_vector("f", x.FV().NumPy(), self.ndof)
        out = _check_vector("result", y.FV().NumPy(), self.ndof)
        out[:] = self.solve(f)

    def MultAdd(self, s: float, x: Any, y: Any) -> None:
        self._check_unchanged()
        f = _check_vector("f", x.FV().NumPy(), self.ndof)
        out = _check_vector("result", y.FV().NumPy(), self.ndof)
        out[:] += s * self.solve(f)

    def MultTrans(self, x: Any, y: Any) -> None:
        """The inverse of a symmetric form is symmetric."""
        self.Mult(x, y)

    @property
    def H(self) -> DDInverse:
        """The conjugate transpose: this inverse itself (real and symmetric).

        NGSolve's own ``.H`` (``ConjTrans``) calls ``MultConjTransAdd``, which a Python matrix cannot
        override and which reads a real vector as complex numbers: garbage, not an error (a review).
        """
        return self

    # ------------------------------------------------------------- solves
    def _condensed(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Free rhs, bubbles condensed, shape (ndof,), and the bubble loads (n_elements, n_b) or None."""
        f = np.where(self.io_free, f, 0.0)
        c = self.cond_data
        fb = None
        if c.b.size:
            fb = f[self.T_b]
            g = np.einsum("ebw,eb->ew", c.E, fb)
            f = f - np.bincount(self.T_w.ravel(), weights=g.ravel(), minlength=f.size)
        return f, fb

    def _primal_load(self, f_condensed: np.ndarray) -> np.ndarray:
        """The W load (scaled, in the primal space) of a condensed rhs of shape (ndof,)."""
        sub = self.sub
        return self.space.to_primal(sub.delta * f_condensed[self.h1_of_gdof][sub.l2g])

    def _condense_rhs(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Free rhs -> W load (bubbles condensed) and the bubble loads (n_elements, n_b)."""
        f, fb = self._condensed(f)
        return self._primal_load(f), fb

    def _residuals(self, u: np.ndarray, f_condensed: np.ndarray) -> tuple[float, float]:
        """||f - A u|| / ||f|| and ||D^{-1/2} (f - A u)|| / ||D^{-1/2} f|| of the condensed problem.

        The condensed problem: the free non-bubble dofs (the bubbles are exact). A u is assembled
        from the subdomain matrices, sum_i R_i^T K_i R_i u: one product with the block-diagonal K_W,
        shape (n_W, n_W). D = diag(A) = sum_i R_i^T diag(K_i), positive for an SPD form. Both are
        absolute residuals when f = 0.

        The scaled one is the residual of the Jacobi-scaled equations: the Krylov rules of FETI-DP
        and FETI measure the dual residual, the jump B u, and a jump of size e in a part with
        coefficient rho leaves a residual of size rho e there, so with a coefficient jump of 1e6 a
        solution with an energy error of 2e-7 read ||f - A u|| / ||f|| = 1.2e-4 (order 2, rtol
        1e-8; docs/ngsolve.md). D^{-1/2} divides that factor out; where the diagonal is uniform the
        two agree.
        """
        sub = self.sub
        f_g, u_g = f_condensed[self.h1_of_gdof], u[self.h1_of_gdof]
        r = np.bincount(sub.l2g, weights=sub.K_W @ u_g[sub.l2g], minlength=f_g.size) - f_g
        w = self._inv_sqrt_diag
        out = []
        for res, rhs in ((r, f_g), (r * w, f_g * w)):
            norm_f = float(np.linalg.norm(rhs))
            out.append(float(np.linalg.norm(res)) / (norm_f if norm_f > 0 else 1.0))
        return out[0], out[1]

    def _error_estimate(self, u: np.ndarray, f_condensed: np.ndarray) -> float:
        """Estimated relative energy error of a solve, :func:`ddsolve.dd.check.energy_error_estimate` on the
        condensed problem (its free non-bubble dofs; the bubbles are condensed exactly and carry no error),
        with this inverse's BDDC operators and weights."""
        return energy_error_estimate(self.sub, u[self.h1_of_gdof], self._bddc.primal, self._bddc.schur,
                                     self.space, f=f_condensed[self.h1_of_gdof], weights=self.sub.delta,
                                     precondition=self._bddc.precondition)

    def _expand(self, u_W: np.ndarray, fb: np.ndarray | None, io_only: bool = True) -> np.ndarray:
        """u on the space from the skeleton values u_W and the bubble loads ``fb``; with ``io_only``
        zero outside the dofs a solve returns (the cell dofs of a form with condense=True)."""
        u = np.zeros(self._n_space)
        u[self.h1_of_gdof] = self.sub.average(self.space.from_primal(u_W))
        c = self.cond_data
        if c.b.size:
            uw = u[self.T_w]
            ub = np.einsum("ebc,ec->eb", c.Kbb_inv, fb) - np.einsum("ebw,ew->eb", c.E, uw)
            u[self.T_b] = ub
        return np.where(self.io_free, u, 0.0) if io_only else u

    def solve(self, f: np.ndarray) -> np.ndarray:
        """u with A u = f on the free dofs, zero elsewhere; f, u of shape (ndof,)."""
        t = time.perf_counter()
        self._check_unchanged()
        f = self._to_space(_check_vector("f", f, self.ndof))
        # solve for f / 2^e with max |f| ~ 2^e: exact (a power of two), so the iterations and the result are
        # those of f, and a load near the overflow or underflow limits does not overflow the norms
        exponent = int(np.frexp(np.max(np.abs(f), initial=0.0))[1]) if np.all(np.isfinite(f)) else 0
        f = np.ldexp(f, -exponent)
        f_condensed, fb = self._condensed(f)
        f_W = self._primal_load(f_condensed)
        if self.method == "bddc" or self._bddc.n_g == 0:
            u_W, kr = self._bddc.solve(f_W, self.rtol, self.maxiter, self.want_cond)
        elif self.method == "fetidp":
            u_W, kr = self._fetidp.solve(f_W, self.rtol, self.maxiter, self.want_cond)
        else:
            u_W, kr = self._feti.solve(f_W, self.rtol, self.maxiter, self.want_cond)
        # the residuals of f itself (absolute, as documented): those of f / 2^e times 2^e (a review: they were
        # the rescaled problem's, ~12 whatever the size of the load)
        self.iterations, self.residuals, self.cond = kr.iterations, np.ldexp(kr.residuals, exponent), kr.cond
        self.converged, self.reason = kr.converged, kr.reason
        # the checks below read every free dof: with condense=True the cell dofs are solved for too (as
        # skeleton nodes where a dropped or fixed cell dof kept them from being condensed), zeroed only after
        u = self._expand(u_W, fb, io_only=False)
        # never call a wrong answer converged: the Krylov rule measures the interface or dual problem,
        # so the error of the assembled equations is estimated too (a singular or inconsistent problem,
        # or a dual rule that does not bound the error, fails here)
        self.relative_residual, self.scaled_residual = self._residuals(u, f_condensed)
        self.error_estimate = self._error_estimate(u, f_condensed)
        limit = self.error_limit
        if self.converged and not self.error_estimate <= limit:
            self.converged = False
            self.reason = (f"the solution does not satisfy A u = f to the tolerance: estimated relative energy "
                           f"error sqrt(r^T M^-1 r / f^T u) = {self.error_estimate:.1e} > {limit:.1e} "
                           f"(min({ERROR_FACTOR:g} rtol, {ERROR_CAP:g}), at least {ERROR_FLOOR:g}) although the {self.method} "
                           f"iteration met its rule "
                           f"({kr.reason}); the problem is singular or too ill-conditioned, or this method's rule "
                           f"does not bound the error here (use method='bddc', or a lower rtol)")
        u = self._from_space(np.ldexp(np.where(self.io_free, u, 0.0), exponent))
        if not self.converged:
            log.warning("DDInverse: %s", self.reason)
            warnings.warn(f"DDInverse did not converge: {self.reason}", ConvergenceWarning, stacklevel=3)
        self.timings["solve"] = time.perf_counter() - t
        return u

    @property
    def error_limit(self) -> float:
        """The largest :attr:`error_estimate` a converged solve may have (:func:`~ddsolve.krylov.convergence.error_limit`)."""
        return error_limit(self.rtol)

    @property
    def preconditioner(self) -> DDPreconditioner:
        """One BDDC application (full space, bubbles exact) as a BaseMatrix for NGSolve's Krylov solvers."""
        return DDPreconditioner(self)


class DDPreconditioner(ngsolve.BaseMatrix):
    """P = H M_BDDC H^T + blockdiag(A_II^{-1}) (with exact element-bubble condensation), symmetric."""

    def __init__(self, inv: DDInverse) -> None:
        super().__init__()
        self.inv = inv

    def Height(self) -> int:
        return self.inv.ndof

    def Width(self) -> int:
        return self.inv.ndof

    def IsComplex(self) -> bool:
        return False

    def CreateColVector(self):
        return ngsolve.BaseVector(self.inv.ndof, False)

    def CreateRowVector(self):
        return ngsolve.BaseVector(self.inv.ndof, False)

    def CreateVector(self, colvector: bool = False):
        return ngsolve.BaseVector(self.inv.ndof, False)

    def Mult(self, x: Any, y: Any) -> None:
        inv = self.inv
        inv._check_unchanged()
        f = _check_vector("f", x.FV().NumPy(), inv.ndof)
        out = _check_vector("result", y.FV().NumPy(), inv.ndof)
        f_W, fb = inv._condense_rhs(inv._to_space(f))
        out[:] = inv._from_space(inv._expand(inv._bddc.precondition(f_W), fb))

    def MultTrans(self, x: Any, y: Any) -> None:
        """P is symmetric."""
        self.Mult(x, y)

    @property
    def H(self) -> DDPreconditioner:
        """The conjugate transpose: P itself (real and symmetric; see :attr:`DDInverse.H`)."""
        return self
