"""KKT residuals (5.5) and energy of a distributed contact solution, from the ranks' own subdomains.

The serial :meth:`ddsolve.contact.problem.ContactProblem.kkt` and
:meth:`~ddsolve.contact.problem.ContactProblem.energy` evaluate, on the
assembled u = R_D^T u_W (the solution a distributed solve gathers on rank 0),

    feasibility       max(B u)_+ / ||u||_inf
    dual feasibility  max(-lambda)_+ / ||lambda||_inf
    complementarity   |lambda^T B u| / (||lambda||_1 ||u||_inf)
    stationarity      ||K u - f + B^T lambda||_2 / (||f||_2 + ||B^T lambda||_2)
    energy            J(u) = 1/2 u^T K u - f^T u.

:func:`distributed_kkt` computes the same numbers with no assembled matrix and
no vector of all dofs on any rank. Each rank holds its subdomains' W vectors
(u_i, K_i, f_i), the values of the interface/contact dofs its subdomains touch
(the u_Gamma space of :class:`~ddsolve.parallel.hybrid.DistributedHybrid`) and
replicated contact-size arrays (lambda, n_c doubles):

* u = R_D^T u_W on the u_Gamma dofs: the delta-weighted sum of the copies,
  summed over ranks by the neighbour sum (in the order of ``gather_solution``,
  so the values are bitwise those of the gathered u); interior dofs have one
  copy (delta = 1);
* B u: the two dofs of every pair from the rank owning them, one Allreduce of
  2 n_c doubles; ||u||_inf one Allreduce(MAX); so feasibility, dual
  feasibility and complementarity are bitwise the serial values;
* K u - f = sum_i R_i^T (K_i u_i - f_i): local products, interface entries
  summed by the neighbour sum, then B^T lambda added at the contact dofs;
  its 2-norm and ||f||_2 over the entries each rank owns
  (:class:`~ddsolve.parallel.krylov.Reductions`, scaled when the squares
  would under/overflow);
* J(u) = sum_i (1/2 u_i^T K_i u_i - f_i^T u_i): one Allreduce of two doubles;
* the penetration weighted by the stiffness
  (:meth:`~ddsolve.contact.problem.ContactProblem.weighted_feasibility`): |diag K| summed on u_Gamma as
  u, ||D u||_inf in the same Allreduce(MAX) as ||u||_inf and the pairs' diagonal entries in the
  same Allreduce as their u.

Stationarity and energy differ from the serial values of the same (u, lambda)
by the summation order of K u only (tests/unit/parallel/test_kkt_mpi.py,
measured: <= 1e-15 absolute and <= 2e-14 relative; where K u cancels strongly
against f, as much as the serial value moves under another order, docs/parallel.md).

No Python loop over subdomains; the arrays are this rank's W vectors, its
u_Gamma values and contact-size (n_c) arrays.
"""
from __future__ import annotations

import math

import numpy as np

from ..contact.problem import KKTResiduals, series_stiffness, weighted_penetration
from ..contact.run import ContactMeasures
from ..krylov.convergence import norm2
from .krylov import Reductions

__all__ = ["distributed_kkt", "gamma_diagonal"]


def _assembled_gamma(dh, w: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """sum_i R_i^T (weights w_i) on this rank's u_Gamma dofs, summed over ranks (one neighbour sum)."""
    g = dh.gamma
    return g.exchange.sum(g.space.gather(w, weights))


def gamma_diagonal(dh) -> np.ndarray:
    """|diag K| of the assembled K on this rank's u_Gamma dofs: the subdomains' diagonals summed over their
    copies and ranks (one neighbour sum), shape (dh.gamma.n,)."""
    return _assembled_gamma(dh, np.abs(dh.prob.sub.K_W.diagonal()), None)


def distributed_kkt(dh, u_gamma: np.ndarray | None, lam: np.ndarray) -> ContactMeasures:
    """KKT residuals (5.5) and energy of the face solution with u_Gamma ``u_gamma`` (collective).

    Parameters
    ----------
    dh : DistributedHybrid
        The distributed hybrid operators of the solve (this rank's subdomains, u_Gamma space,
        contact pairs ``dh.pair_dofs``).
    u_gamma : ndarray, shape (dh.gamma.n,), or None
        This rank's u_Gamma values of the solution (consistent copies); u = R_D^T u_W with u_W its
        interior completion (``DirichletSchur.interior_solution``, as the face solve). None: u = 0
        (no face solve ran).
    lam : ndarray, shape (n_c,)
        Contact multipliers, replicated on every rank.

    Returns
    -------
    ContactMeasures
        The same on every rank.
    """
    sub, comm, g = dh.prob.sub, dh.comm, dh.gamma
    lam = np.asarray(lam, dtype=float)
    on_gamma = dh.schur.gamma                                   # (n_W,) bool, this rank's W entries
    if u_gamma is None:
        u_W = np.zeros(sub.n_W)
    else:
        u_W = dh.schur.interior_solution(sub.f_W, g.space.scatter(np.asarray(u_gamma, dtype=float)))
    # u = R_D^T u_W: delta-weighted copies on u_Gamma (as gather_solution), one copy elsewhere
    u_g = _assembled_gamma(dh, u_W, sub.delta[g.space.idx])
    u_W = np.where(on_gamma, g.space.scatter(u_g), u_W)         # u_i = R_i u, consistent copies
    interior = ~on_gamma

    # |diag K| of the assembled K: summed copies on u_Gamma, one copy elsewhere (the weighted feasibility)
    d_g = gamma_diagonal(dh)
    d_W = np.where(on_gamma, g.space.scatter(d_g), np.abs(sub.K_W.diagonal()))

    # ||u||_inf (NaN anywhere: NaN, as np.abs(u).max() in serial) and ||D u||_inf, one Allreduce(MAX)
    absu = np.abs(u_W)
    bad = bool(np.isnan(absu).any())
    local_max = float(np.max(absu, initial=0.0, where=~np.isnan(absu)))
    force_max = float(np.max(d_W * absu, initial=0.0, where=~np.isnan(absu)))
    both = np.empty(3)
    comm.comm.Allreduce(np.array([local_max, float(bad), force_max]), both, op=comm.MPI.MAX)
    comm.counters.allreduces += 1
    u_inf = math.nan if both[1] > 0.0 else max(float(both[0]), 1e-300)
    force_scale = math.nan if both[1] > 0.0 else float(both[2])

    # the gap B u = u^1 - u^2 at the pairs and the pairs' |diag K|: each dof from the rank owning it,
    # one Allreduce of 4 n_c
    pair_values = np.zeros((2,) + dh.pair_dofs.shape)              # u and |diag K| at the pairs' dofs
    pos = g.local_index(dh.pair_dofs)
    mine = pos >= 0
    mine[mine] = g.owned[pos[mine]]
    pair_values[0][mine] = u_g[pos[mine]]
    pair_values[1][mine] = d_g[pos[mine]]
    pair_u, pair_d = comm.allreduce_sum(pair_values.ravel()).reshape((2,) + dh.pair_dofs.shape)
    gap = pair_u[:, 0] - pair_u[:, 1]

    l_inf = float(np.abs(lam).max()) if lam.size else 0.0
    l_one = float(np.abs(lam).sum())
    feas = max(float(gap.max(initial=0.0)), 0.0) / u_inf + 0.0
    dual = max(float((-lam).max(initial=0.0)), 0.0) / l_inf + 0.0 if l_inf > 0 else 0.0
    comp = abs(float((lam / l_one) @ (gap / u_inf))) if l_one > 0 else 0.0

    # K u - f + B^T lambda = sum_i R_i^T (K_i u_i - f_i) + B^T lambda, entries owned once
    Ku_W = sub.K_W @ u_W
    f_g = _assembled_gamma(dh, sub.f_W, None)
    Ku_g = _assembled_gamma(dh, Ku_W, None)
    contact_g = np.zeros(g.n)                                   # B^T lambda on this rank's u_Gamma dofs
    for side, sign in ((0, 1.0), (1, -1.0)):
        held = pos[:, side] >= 0
        np.add.at(contact_g, pos[held, side], sign * lam[held])
    # B^T lambda replicated on the contact dofs only (2 n_c doubles), for ||B^T lambda||_2
    _, slot = np.unique(dh.pair_dofs.ravel(), return_inverse=True)
    contact = np.bincount(slot.ravel(), weights=np.stack([lam, -lam], axis=1).ravel()).astype(float)
    r_g = Ku_g - f_g + contact_g
    r_interior = Ku_W[interior] - sub.f_W[interior]
    owned = np.concatenate([np.ones(int(interior.sum()), dtype=bool), g.owned])
    red = Reductions(comm, owned)
    f_norm = red.l2norm(np.concatenate([sub.f_W[interior], f_g]))
    r_norm = red.l2norm(np.concatenate([r_interior, r_g]))
    scale = f_norm + norm2(contact)
    stat = r_norm / scale if scale > 0.0 else 0.0

    sums = comm.allreduce_sum(np.array([float(u_W @ Ku_W), float(sub.f_W @ u_W)]))
    energy = float(0.5 * sums[0] - sums[1])
    weighted = weighted_penetration(gap, series_stiffness(pair_d[:, 0], pair_d[:, 1]), force_scale)
    kkt = KKTResiduals(feas, dual, comp, stat)
    if both[1] > 0.0 or not np.all(np.isfinite(lam)):    # as serial: non-finite u or lambda is no solution (both
        kkt = KKTResiduals(math.nan, math.nan, math.nan, math.nan)     # global: u's flag reduced, lambda replicated)
    return ContactMeasures(kkt=kkt, energy=energy,
                           n_contact=int(dh.pair_dofs.shape[0]), weighted_feasibility=weighted)
