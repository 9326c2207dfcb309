"""Distributed active set method (Chapter 5): the serial loop, distributed hybrid face solves.

The serial :class:`~ddsolve.contact.active_set.ActiveSetHybrid` runs unchanged
(:class:`DistributedActiveSetHybrid` is a subclass): its logic (the PCG on
(5.4), MPRGP for the projection of Figure 5.1, the sign tests and the updates
of the active set) acts on vectors of the contact interface only, which are
kept **replicated** on every rank:

* multipliers lambda, lambda*, lambda^, the gap B^ u: n_c doubles (the
  contact pairs; 2 (N m) + 1 for two membranes of N x N subdomains with H/h = m);
* u_Gamma between face solves (the warm start and the face minimizer the loop
  tests): n_Gamma doubles, the body-interface dofs (not all dofs), made
  replicated once per face solve by one Allreduce.

Every product that reaches the subdomains is distributed: the operator of
(5.4), B^ P_R M_BDDC^{-1} P_R B^T, and the preconditioner B^_D S^_c B^_D^T
apply the distributed hybrid operators (:class:`~ddsolve.parallel.hybrid.DistributedHybrid`)
to this rank's u_Gamma dofs and return replicated multipliers (one Allreduce
of n_c doubles); the face solves are the distributed hybrid PCR. Since every
rank holds the same replicated values, every rank takes the same decisions:
the same active sets, outer iterations and iteration counts.

The KKT residuals (5.5) and the energy of the result are computed distributed
as well (:meth:`DistributedActiveSetHybrid.measures`, :mod:`ddsolve.parallel.kkt`):
no rank assembles K, f or B.
"""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..contact.active_set import ActiveSetHybrid
from ..contact.direct import ContactSolution
from ..contact.run import ContactMeasures
from ..dd.common import MethodOutput
from ..dd.projection import Projection
from ..multibody.interface import UNTIED_MESSAGE, UNTIED_TOL
from .hybrid import DistributedHybrid
from .kkt import distributed_kkt, gamma_diagonal
from .setup import RankProblem

__all__ = ["ReplicatedHybrid", "DistributedActiveSetHybrid"]


class _ReplicatedPairs:
    """The serial ``ActiveSet`` fields the loop reads, on replicated vectors: the jump and P^k."""

    def __init__(self, first: np.ndarray, second: np.ndarray, n_gamma: int, projection: Projection | None) -> None:
        self.first, self.second, self.n_gamma = first, second, n_gamma
        self.projection = projection


class ReplicatedHybrid:
    """The interface of :class:`~ddsolve.multibody.hybrid.HybridSolver` that the active set loop uses,
    on replicated u_Gamma (global numbering) and multiplier vectors, backed by a :class:`DistributedHybrid`.

    Parameters
    ----------
    dh : DistributedHybrid
    """

    def __init__(self, dh: DistributedHybrid, gather: bool = True) -> None:
        self.dh = dh
        self.gather = gather                 # the global u of each face solve on rank 0 (else u is None)
        comm = dh.comm
        self.comm = comm
        self.gamma_dofs = dh.gamma_dofs                                    # global u_Gamma numbering
        self.n_gamma = int(self.gamma_dofs.size)
        self._gpos = np.searchsorted(self.gamma_dofs, dh.gamma.space.dofs)  # local -> global position
        self._gpos_owned = self._gpos[dh.gamma.owned]
        self.floating = dh.floating
        self.n_factorizations = dh.n_factorizations
        self.setup_seconds = dh.setup_seconds
        self.g_hat = self.to_global(dh.g_hat)
        self._pair_gamma = np.searchsorted(self.gamma_dofs, dh.pair_dofs)   # (n_gl, 2)
        self.face_solves: list[dict] = []
        self.last_u_gamma: np.ndarray | None = None       # this rank's u_Gamma of the last face solve

    # -------------------------------------------------------------- layout
    def to_local(self, u: np.ndarray) -> np.ndarray:
        """This rank's entries of a replicated u_Gamma."""
        return u[self._gpos]

    def to_global(self, u_loc: np.ndarray) -> np.ndarray:
        """Replicated u_Gamma from consistent local values (one Allreduce of n_Gamma doubles)."""
        out = np.zeros(self.n_gamma)
        out[self._gpos_owned] = u_loc[self.dh.gamma.owned]
        return self.comm.allreduce_sum(out)

    def replicate_rows(self, a, values: np.ndarray, n: int) -> np.ndarray:
        """Replicated multipliers (length n) from this rank's rows ``a.rows`` (one Allreduce of n doubles)."""
        out = np.zeros(n)
        o = a.shared.owned
        out[a.rows[o]] = values[o]
        return self.comm.allreduce_sum(out)

    # ------------------------------------------------------ serial interface
    def active_set(self, active: np.ndarray) -> _ReplicatedPairs:
        dh = self.dh
        active = np.asarray(active, dtype=bool)
        first, second = self._pair_gamma[active, 0], self._pair_gamma[active, 1]
        projection = None
        k = dh.floating.size
        if k:                                  # G^k = Z B^ R_c, replicated (n_act x k), as HybridSolver
            bodies = dh.pair_body[active]
            c1, c2 = dh._column_of_body[bodies[:, 0]], dh._column_of_body[bodies[:, 1]]
            r = np.arange(first.size)
            G = sp.csr_matrix((np.r_[np.ones(int((c1 >= 0).sum())), -np.ones(int((c2 >= 0).sum()))],
                               (np.r_[r[c1 >= 0], r[c2 >= 0]], np.r_[c1[c1 >= 0], c2[c2 >= 0]])),
                              shape=(first.size, k))
            projection = Projection(G, singular_tol=UNTIED_TOL, singular_message=UNTIED_MESSAGE)
        return _ReplicatedPairs(first, second, self.n_gamma, projection)

    def jump(self, a: _ReplicatedPairs, u: np.ndarray) -> np.ndarray:
        """Z B^ u on a replicated u_Gamma (no communication)."""
        return u[a.first] - u[a.second]

    def jump_transpose(self, a: _ReplicatedPairs, lam: np.ndarray) -> np.ndarray:
        return (np.bincount(a.first, weights=lam, minlength=self.n_gamma).astype(np.float64, copy=False)
                - np.bincount(a.second, weights=lam, minlength=self.n_gamma))

    def kernel_load(self) -> np.ndarray:
        return self.dh.kernel_load()

    def P_R(self, u: np.ndarray) -> np.ndarray:
        return self.to_global(self.dh.P_R(self.to_local(u)))

    def M_bddc(self, r: np.ndarray) -> np.ndarray:
        return self.to_global(self.dh.M_bddc(self.to_local(r)))

    def S_hat(self, u: np.ndarray) -> np.ndarray:
        return self.to_global(self.dh.S_hat(self.to_local(u)))

    def solve(self, active: np.ndarray, *, rtol: float, maxiter: int, x0: dict, rtol_rule: str = "max",
              **options: Any) -> MethodOutput:
        """A distributed face solve; ``extra["lambda"]`` (active multipliers) and ``extra["u_gamma"]`` replicated."""
        dh = self.dh
        options.pop("check", None)      # a face solve is judged by the KKT conditions: no error check (as serial)
        options.pop("interior", None)   # no u per face: DistributedActiveSetHybrid.face_u gathers the last one
        x0_loc = {"u_gamma": self.to_local(np.asarray(x0["u_gamma"], dtype=float)), "lambda": x0["lambda"]}
        out, info = dh.solve(active, rtol=rtol, maxiter=maxiter, rtol_rule=rtol_rule, x0=x0_loc,
                             gather=False, **options)
        a = dh.active_set(active)
        self.face_solves.append(info)
        self.last_u_gamma = out.extra["u_gamma"]
        extra = dict(out.extra)
        extra["lambda"] = self.replicate_rows(a, out.extra["lambda"], a.n_active)
        extra["u_gamma"] = self.to_global(out.extra["u_gamma"])
        return MethodOutput(u=out.u, krylov=out.krylov, nlambda=out.nlambda, n_factorizations=0,
                            setup_seconds=out.setup_seconds, extra=extra)


class DistributedActiveSetHybrid(ActiveSetHybrid):
    """:class:`ActiveSetHybrid` on the ranks of ``prob.comm`` (see the module docstring).

    The loop of :meth:`ActiveSetHybrid.solve` is inherited; the operator and the
    preconditioner of (5.4) are overridden to act on this rank's u_Gamma dofs.

    Parameters
    ----------
    prob : RankProblem
        Of a contact problem (its pieces from :func:`~ddsolve.parallel.hybrid.distribute_hybrid`).
    gather : bool
        Assemble the global solution u on rank 0 (the solution's ``u``; ``None`` without): only
        for a caller that needs it (the API, ``--check``); the KKT residuals do not.
    """

    def __init__(self, prob: RankProblem, gather: bool = True) -> None:
        self.dh = DistributedHybrid(prob)
        rep = ReplicatedHybrid(self.dh, gather=gather)
        n_c = self.dh.n_gl
        self.problem = SimpleNamespace(n_contact=n_c, ndof=int(prob.ndof))
        self.hybrid = rep
        self.n_contact = n_c
        self.all_pairs = rep.active_set(np.ones(n_c, dtype=bool))
        self._pairs = self.dh.active_set(np.ones(n_c, dtype=bool))     # this rank's rows of all pairs

    def face_u(self, out: MethodOutput) -> np.ndarray | None:
        """The global u of the last face solve on rank 0 (``gather``; None without, and on the other ranks).

        Collective with ``gather`` (:meth:`~ddsolve.parallel.hybrid.DistributedHybrid.gathered_u`), once per
        solve instead of once per face solve.
        """
        return self.dh.gathered_u(self.hybrid.last_u_gamma) if self.hybrid.gather else None

    def measures(self, sol: ContactSolution) -> ContactMeasures:
        """KKT residuals (5.5) and energy of ``sol`` (the last face solve's u), computed distributed.

        Collective; the same on every rank. u is that of the last face solve (``sol.u`` on rank 0,
        :func:`~ddsolve.parallel.kkt.distributed_kkt`), lambda the replicated ``sol.lam``.
        """
        return distributed_kkt(self.dh, self.hybrid.last_u_gamma, sol.lam)

    def gamma_stiffness(self) -> np.ndarray:
        """|diag K| on the u_Gamma dofs, replicated: :func:`~ddsolve.parallel.kkt.gamma_diagonal` (one
        neighbour sum), then made replicated (one Allreduce of n_Gamma doubles)."""
        return self.hybrid.to_global(gamma_diagonal(self.dh))

    def coefficient_scale(self) -> float:
        """max_i rho_i over the subdomains of all ranks (one Allreduce)."""
        rho = np.asarray(self.dh.prob.sub.rho, dtype=float)
        return self.dh.comm.allreduce_scalar(float(rho.max()) if rho.size else 0.0, op="max") or 1.0

    def S_dagger(self, r: np.ndarray) -> np.ndarray:
        """P_R M_BDDC^{-1} P_R r on a replicated u_Gamma (replicated result)."""
        h = self.hybrid
        dh = self.dh
        return h.to_global(dh.P_R(dh.M_bddc(dh.P_R(h.to_local(r)))))

    def F(self, lam: np.ndarray) -> np.ndarray:
        """B^ P_R M_BDDC^{-1} P_R B^T lam, replicated in and out (one Allreduce of n_c doubles)."""
        a, dh = self._pairs, self.dh
        t = a.jump.rmatvec(lam[a.rows])
        y = a.jump.matvec(dh.P_R(dh.M_bddc(dh.P_R(t))))
        return self.hybrid.replicate_rows(a, y, self.n_contact)

    def preconditioner(self, lam: np.ndarray) -> np.ndarray:
        """B^_D S^_c B^_D^T lam, replicated in and out."""
        a, dh = self._pairs, self.dh
        y = a.scaled_jump_gamma.matvec(dh.S_hat(a.scaled_jump_gamma.rmatvec(lam[a.rows])))
        return self.hybrid.replicate_rows(a, y, self.n_contact)
