"""The final error check of the multibody solvers (FETI-FETI, hybrid): the error of u on the tied problem.

FETI-FETI's rule measures the dual residual of (3.35). As for one-level FETI (:mod:`ddsolve.dd.check`),
how well that bounds the error of the averaged u depends on the scaling: with multiplicity scaling and
coefficients jumping by 1e12 between subdomains a solve that met rtol 1e-6 was 230% off.

The equality-constrained multibody problem with active pairs Z (min 1/2 u^T A u - f^T u subject to
u_a = u_b on every active pair, :mod:`ddsolve.multibody.direct`) is one Poisson problem on the *tied*
mesh: the nodes that active pairs identify merged into one (the connected components of the pair
graph), the untied parts of a body interface left as cracks. :func:`tied_substructures` builds the
subdomains of that problem from the same subdomain matrices (the same local order, so the same
templates), and :func:`multibody_error_estimate` applies :func:`ddsolve.dd.check.energy_error_estimate`
there: sqrt(r^T M^{-1} r / f^T u) with a BDDC preconditioner of all subdomains of all bodies
(rho-scaling, cross points of the tied mesh primal), an upper bound of the relative energy error.
It costs one primal-constrained and one Dirichlet factorization of the tied subdomains.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse import csgraph

from ..dd.check import energy_error_estimate, judge_output, needs_check
from ..dd.common import MethodOutput
from ..dd.operators import DirichletSchur, PrimalConstrainedSolver
from ..dd.projection import DENSE_COARSE_MAX
from ..dd.substructure import Substructures
from ..scene.assembly import LocalProblems
from ..scene.scene import Scene
from .interface import GlobalInterface

__all__ = ["tied_nodes", "tied_scene", "tied_substructures", "floating_shifts", "multibody_error_estimate",
           "checked_output"]


def tied_nodes(sub: Substructures, gi: GlobalInterface, active: np.ndarray) -> tuple[int, np.ndarray]:
    """The node numbering of the tied mesh: nodes joined by active pairs share one number.

    Parameters
    ----------
    sub : Substructures
    gi : GlobalInterface
    active : ndarray of bool, shape (gi.n_gl,)

    Returns
    -------
    n_nodes : int
    label : ndarray of int, shape (sub.scene.n_nodes,)
        The tied node of every node (its connected component in the graph of the active pairs).
    """
    n = sub.scene.n_nodes
    pairs = gi.pair_nodes[np.asarray(active, dtype=bool)]
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    n_tied, label = csgraph.connected_components(graph, directed=False)
    return int(n_tied), label


def tied_scene(scene: Scene, n_tied: int, label: np.ndarray) -> Scene:
    """``scene`` on the tied node numbering (:func:`tied_nodes`), as one body.

    The subdomains, their elements (renumbered) and coefficients are ``scene``'s; the tied nodes
    coincide, so each subdomain lists its nodes in the same canonical order (the W layout and the
    templates are kept). The cross points are those of the tied mesh: nodes of three or more
    subdomains, or of two on its boundary (which includes the untied parts of the body interfaces).
    """
    coords = np.empty((n_tied, scene.coords.shape[1]))
    coords[label] = scene.coords                     # tied nodes coincide
    dirichlet = np.zeros(n_tied, dtype=bool)
    dirichlet[label[scene.dirichlet]] = True         # active pairs join free copies only
    return dataclasses.replace(scene, coords=coords, elements=label[scene.elements], dirichlet=dirichlet,
                               subdomain_body=np.zeros(scene.n_subdomains, dtype=np.int64),
                               contact_pairs=np.zeros((0, 2), dtype=np.int64))


def tied_substructures(sub: Substructures, gi: GlobalInterface, active: np.ndarray) -> tuple[Substructures, np.ndarray]:
    """The subdomains of the tied problem (one body), and the map of ``sub``'s dofs to its dofs.

    Parameters
    ----------
    sub : Substructures
        A multibody scene's subdomains (bodies with their own nodes).
    gi : GlobalInterface
    active : ndarray of bool, shape (gi.n_gl,)

    Returns
    -------
    tied : Substructures
        Same subdomains, matrices and loads, on the tied node numbering, rho-scaling.
    dof_map : ndarray of int, shape (sub.ndof,)
        The tied dof of every dof of ``sub``.
    """
    n_tied, label = tied_nodes(sub, gi, active)
    local = sub.local
    tied_local = LocalProblems(scene=tied_scene(sub.scene, n_tied, label),
                               nodes=[label[nodes] for nodes in local.nodes], template=local.template,
                               stiffness=local.stiffness, loads=local.loads)
    tied = Substructures(tied_local, scaling="rho", gamma=1.0, templates=sub.templates)
    free = np.flatnonzero(sub.dof_of_node >= 0)
    dof_map = np.empty(sub.ndof, dtype=np.int64)
    dof_map[sub.dof_of_node[free]] = tied.dof_of_node[label[free]]
    return tied, dof_map


def floating_shifts(node: np.ndarray, body: np.ndarray, weight: np.ndarray, weighted_u: np.ndarray,
                    floating: np.ndarray, n_bodies: int) -> np.ndarray:
    """The constant c_b added to each floating body b before its copies are averaged, shape (n_bodies,).

    A floating body's matrix annihilates the constants, so u + c has the error of u in the bodies'
    energy norm and the estimate stays an upper bound whatever c is. c makes it tight where a floating
    body's u is shifted as a whole (the hybrid method on a body checkerboard, jump 1e6: a stiff body by
    1.4% of its displacement, energy error 1.6e-6 while the tied average of u was 6e-5 off). It
    minimises the weighted spread of the copies, sum_n sum_b W_nb (u_nb + c_b - mean_n)^2 (W_nb, u_nb:
    body b's weight and value at tied node n, mean_n their W-weighted mean), over the floating bodies
    (c = 0 elsewhere): M_ff c_f = r_f with

        M = diag(sum_n W_nb) - W^T diag(1 / S_n) W,   r_b = sum_n W_nb (mean_n - u_nb),   S_n = sum_b W_nb,

    a k x k system (k floating bodies; least squares where floating bodies are tied to nothing else).

    Parameters
    ----------
    node, body, weight, weighted_u : ndarray, shape (m,)
        One row per W entry on the body interfaces (several per (node, body) are summed): its tied node,
        its body, its weight w and w u.
    floating : ndarray of int
        The floating bodies.
    n_bodies : int
    """
    shift = np.zeros(n_bodies)
    floating = np.asarray(floating, dtype=np.int64)
    if floating.size == 0 or node.size == 0:
        return shift
    nodes, row = np.unique(node, return_inverse=True)
    W = sp.csr_matrix((weight, (row, body)), shape=(nodes.size, n_bodies))
    WU = sp.csr_matrix((weighted_u, (row, body)), shape=(nodes.size, n_bodies))
    S = np.asarray(W.sum(axis=1)).ravel()
    mean = np.asarray(WU.sum(axis=1)).ravel() / S
    M = (sp.diags(np.asarray(W.sum(axis=0)).ravel()) - W.T @ sp.diags(1.0 / S) @ W).tocsr()
    rhs = W.T @ mean - np.asarray(WU.sum(axis=0)).ravel()
    M_ff = M[floating][:, floating]
    if floating.size <= DENSE_COARSE_MAX:
        shift[floating] = np.linalg.lstsq(M_ff.toarray(), rhs[floating], rcond=None)[0]
    else:                          # sparse (a dense k x k least squares took 18.5 s at k = 3,844; a review)
        shift[floating] = _laplacian_lstsq(M_ff, rhs[floating])
    return shift


def _laplacian_lstsq(L: sp.csr_matrix, b: np.ndarray) -> np.ndarray:
    """The least-squares solution of minimum norm of L x = b, L (k x k) a weighted graph Laplacian plus a
    nonnegative diagonal (the M_ff of :func:`floating_shifts`), by sparse LU: what ``np.linalg.lstsq`` gives.

    On a connected component with a positive row sum (a floating body tied to a non-floating one) L is
    SPD there and solved as it is. On a component whose rows sum to zero (floating bodies tied to nothing
    else) L annihilates the constants: b is projected onto their complement, one dof of the component is
    pinned to 0, and the solution's mean is then removed (the solution orthogonal to the kernel).
    """
    k = L.shape[0]
    n_comp, label = csgraph.connected_components(L, directed=False)
    row_sum = np.asarray(L.sum(axis=1)).ravel()
    # grounded: a row sum above rounding relative to the largest diagonal entry of L (an untied body's own
    # diagonal is rounding, ~1e-15, and a test relative to it read that as a tie; a review), as lstsq's cutoff
    floor = 1e-12 * float(np.abs(L.diagonal()).max(initial=0.0))
    grounded = np.bincount(label, weights=np.abs(row_sum), minlength=n_comp) > floor
    size = np.bincount(label, minlength=n_comp)
    b = b.astype(float, copy=True)
    floating = ~grounded[label]
    b[floating] -= (np.bincount(label, weights=b, minlength=n_comp) / size)[label][floating]
    _, pin = np.unique(label, return_index=True)                  # the first dof of every component
    keep = np.ones(k, dtype=bool)
    keep[pin[~grounded]] = False
    x = np.zeros(k)
    if keep.any():
        x[keep] = spla.splu(L[keep][:, keep].tocsc()).solve(b[keep])
    x[floating] -= (np.bincount(label, weights=np.where(floating, x, 0.0), minlength=n_comp) / size)[label][floating]
    return x


def multibody_error_estimate(sub: Substructures, gi: GlobalInterface, active: np.ndarray,
                             u: np.ndarray) -> tuple[float, int]:
    """Upper bound of the relative energy error of a multibody solution ``u`` (FETI-FETI, hybrid).

    Parameters
    ----------
    sub : Substructures
    gi : GlobalInterface
    active : ndarray of bool, shape (gi.n_gl,)
        The active pairs of the solve.
    u : ndarray, shape (sub.ndof,)
        The solution, each body's copy of a tied node its own value.

    Returns
    -------
    estimate : float
        eta_t + sqrt((u - u_t)^T A (u - u_t) / f^T u_t): u_t is u (each floating body shifted by its
        :func:`floating_shifts` constant) averaged over the copies of every tied node with the weights of
        their assembled diagonals (the stiff side's value wins), eta_t the
        :func:`ddsolve.dd.check.energy_error_estimate` of the tied problem at u_t, and A the bodies'
        block-diagonal matrix; by the triangle inequality an upper bound of ||u - u*||_A / ||u*||_A up to
        the error in f^T u_t. inf where u is not finite.
    n_factorizations : int
        Those the estimate made (the tied primal-constrained and Dirichlet problems).
    """
    if not np.all(np.isfinite(u)):
        return math.inf, 0
    tied, dof_map = tied_substructures(sub, gi, active)
    diagonal = sub.K_W.diagonal()
    body = sub.body_of_sub[sub.sub_of_W]
    body_of_dof = np.empty(sub.ndof, dtype=np.int64)
    body_of_dof[sub.l2g] = body
    # a floating body's constant is free in ||.||_A: shift it to align its copies with the other bodies'
    on = np.flatnonzero(gi.mask)
    u_W = u[sub.l2g]
    shift = floating_shifts(dof_map[sub.l2g[on]], body[on], diagonal[on], diagonal[on] * u_W[on],
                            gi.floating_bodies(), sub.scene.n_bodies)
    u = u + shift[body_of_dof]
    # the copies of a tied node averaged with the weights of their stiffness (the stiff side's value wins,
    # as rho-scaling would), and the part of u that this moves bounded on its own: with u_t the average,
    # ||u - u*||_A <= ||u_t - u*||_A + ||u - u_t||_A (A: the bodies' block-diagonal matrix)
    weight = sub.assemble_vector(diagonal)
    u_tied = (np.bincount(dof_map, weights=weight * u, minlength=tied.ndof)
              / np.bincount(dof_map, weights=weight, minlength=tied.ndof))
    cache: dict = {}
    primal_solver = PrimalConstrainedSolver(tied, tied.vertex, cache)
    schur = DirichletSchur(tied, tied.interface, cache)
    n_factorizations = primal_solver.n_factorizations + schur.II.n_new_factorizations
    estimate = energy_error_estimate(tied, u_tied, primal_solver, schur)
    moved = (u - u_tied[dof_map])[sub.l2g]
    if not np.any(moved) or not math.isfinite(estimate):
        return estimate, n_factorizations
    f = tied.assemble_vector(tied.f_W)
    exponent = int(np.frexp(np.max(np.abs(f), initial=0.0))[1])       # scale-free, as the estimate
    f, u_tied, moved = (np.ldexp(v, -exponent) for v in (f, u_tied, moved))
    energy = float(f @ u_tied)
    if not energy > 0:
        return math.inf, n_factorizations
    return estimate + math.sqrt(abs(float(moved @ (sub.K_W @ moved))) / energy), n_factorizations


def checked_output(out: MethodOutput, gi: GlobalInterface, active: np.ndarray, rtol: float, method: str,
                   check: bool | None = None) -> MethodOutput:
    """``out`` of a multibody solve (FETI-FETI, hybrid) after the final error check.

    ``check`` None runs it where :func:`ddsolve.dd.check.needs_check` says (coefficient jumps between
    subdomains, or an unstructured mesh); True always, False never (the inner solves of the contact
    methods, whose result is judged by its KKT conditions). A converged ``out`` whose
    :func:`multibody_error_estimate` exceeds the limit comes back not converged
    (:func:`ddsolve.dd.check.judge_output`), the estimate in ``extra["error_estimate"]`` and its
    factorizations counted.
    """
    sub = gi.sub
    if check is None:
        check = needs_check(sub.rho, sub.templates, rtol)
    if not check or out.krylov is None or not out.krylov.converged:
        return out
    out.extra["error_estimate"], n_fact = multibody_error_estimate(sub, gi, active, out.u)
    out.n_factorizations += n_fact
    return judge_output(out, rtol, method)
