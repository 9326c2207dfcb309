"""Subdomain-based operators shared by the FETI, FETI-DP and BDDC solvers.

All operators act on W vectors (see :mod:`ddsolve.dd.substructure`) and are
applied through batched subdomain solves; none forms a global dense matrix.

Operators that only act on the subdomain interfaces can instead use small
dense *local* matrices formed once from the existing factorizations (one per
distinct subdomain, shared by identical ones): the local Schur complements
S_t (:meth:`DirichletSchur.matvec`, ``explicit``), their harmonic extensions
K_II^{-1} K_IG (:meth:`DirichletSchur.interior_solution`) and the interface
block of the primal-constrained inverse (:meth:`PrimalConstrainedSolver.solve_interface`).
One application is then one GEMM per group of the size of the local
interface (O(H/h) unknowns) instead of interior solves with O((H/h)^2)
unknowns and products with K_W. ``space_matvec`` / ``space_solve`` apply them
directly between compact spaces of interface values (no W vectors).

This module holds the Dirichlet Schur complement and the jump operators; the
primal-constrained solver and its interface restrictions live in
:mod:`ddsolve.dd.primal` and are re-exported here.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .local import BatchedSolver, DenseBlocks, solve_many
from .substructure import Substructures

log = logging.getLogger(__name__)

#: ``explicit=None`` (auto) forms the local Schur complements explicitly when their setup
#: (one local solve per interface unknown of each distinct subdomain) costs at most this
#: many applications of the implicit operator (one batched solve each).
EXPLICIT_SETUP_MATVECS = 16
#: Largest local interface (or primal-free interface) block formed explicitly (dense, n^2 doubles).
EXPLICIT_MAX_BLOCK = 4000
#: Memory budget of the explicit harmonic extensions K_II^{-1} K_IG kept by an explicit
#: :class:`DirichletSchur` (dense n_I x n_G per group) for :meth:`DirichletSchur.interior_solution`.
EXPLICIT_EXTENSION_BYTES = 512 * 2**20
#: Harmonic extensions solved at once while explicit blocks are formed without keeping them (a
#: window of columns of all of them; at least one column, which exceeds this beyond 4M interior rows).
EXPLICIT_BUILD_BYTES = 32 * 2**20


@dataclass
class _SchurGroup:
    """Subdomains sharing one explicit local Schur complement: template, local interior/interface sets."""

    template: int
    interior_local: np.ndarray
    gamma_local: np.ndarray
    members: list[int]


@dataclass
class ExtensionBlock:
    """Explicit harmonic extension K_II^{-1} K_IG of one group and the W positions of its members."""

    extension: np.ndarray           # (n_i, n_g)
    gamma_index: np.ndarray         # (n_g, n_members)
    interior_index: np.ndarray      # (n_i, n_members)


@dataclass
class HarmonicExtensions:
    """All explicit harmonic extensions, with the flat W positions of their interface and interior entries."""

    blocks: list[ExtensionBlock]
    flat_gamma: np.ndarray
    flat_interior: np.ndarray


@dataclass
class _InteriorLoad:
    """The last interior load A_II^{-1} f (``source`` the array passed, ``values`` its copy)."""

    source: np.ndarray
    values: np.ndarray
    solution: np.ndarray


@dataclass
class SchurSpaceMatvec:
    """gather_out(S scatter_in(u)) on compact index maps (:meth:`DirichletSchur.space_matvec`).

    Attributes
    ----------
    blocks : DenseBlocks
        The local Schur complements of the subdomains touching both spaces.
    index_in : ndarray of int, shape (blocks.size,)
        Index into the concatenated input values (their total size: the appended zero).
    index_out : ndarray of int, shape (blocks.size,)
        Output index of every block entry (-1 outside the output space).
    out_select : ndarray of int or None
        Block entries inside the output space (None: all).
    n_out : int
    """

    blocks: DenseBlocks
    index_in: np.ndarray
    index_out: np.ndarray
    out_select: np.ndarray | None
    n_out: int

    def apply(self, us: list[np.ndarray]) -> np.ndarray:
        u_ext = np.concatenate(list(us) + [np.zeros(1)])
        ys = self.blocks.apply(u_ext[self.index_in])
        if self.out_select is None:
            return np.bincount(self.index_out, weights=ys, minlength=self.n_out)
        return np.bincount(self.index_out[self.out_select], weights=ys[self.out_select], minlength=self.n_out)


class DirichletSchur:
    """Local Schur complements S = diag(S^(i)) applied on the interface (Section 2.4).

    S^(i) = A_GG^(i) - A_GI^(i) A_II^(i)^{-1} A_IG^(i), applied as
    S w = (K w - K A_II^{-1} (K w)_I)_Gamma for w supported on the interface
    entries, with one batched interior (Dirichlet) solve.

    Parameters
    ----------
    sub : Substructures
    gamma_mask : ndarray of bool, shape (n_W,)
        The local interface Gamma_i; everything else free is interior.
    cache : dict
        Shared factorization cache.
    exclude : ndarray of bool, shape (n_W,), optional
        Entries treated as Dirichlet nodes (removed from the interior).
    explicit : bool, optional
        Apply S through explicitly formed dense local Schur complements
        S_t = K_GG - K_GI K_II^{-1} K_IG, one per distinct (template, interior
        set, interface set), scaled by rho_i: one GEMM per group of the size of
        the local *interface* instead of two sparse products with K_W and an
        interior solve. Formed on the first :meth:`matvec` from the existing
        interior factorizations (no new factorization). ``None`` (default):
        explicit when that setup costs at most ``EXPLICIT_SETUP_MATVECS``
        implicit applications and no block exceeds ``EXPLICIT_MAX_BLOCK``; otherwise
        implicit until the applications made have cost as much as that setup, then explicit
        (rent or buy: a long run such as the active set method's face solves pays at most
        twice the better choice, a short one never the setup). ``False``: always implicit.
        The result is the same operator up to rounding.
    """

    def __init__(self, sub: Substructures, gamma_mask: np.ndarray, cache: dict,
                 exclude: np.ndarray | None = None, explicit: bool | None = None) -> None:
        self.sub = sub
        self.gamma = gamma_mask
        self.interior = ~gamma_mask if exclude is None else ~gamma_mask & ~exclude
        self.II = BatchedSolver(sub, self.interior, cache)
        self._cache = cache
        self._explicit_option = explicit
        self._blocks: DenseBlocks | None | bool = None      # None: not decided yet; False: implicit
        self._switch_after: float | None = None     # implicit: applications after which explicit pays off
        self._implicit_applications = 0
        self._space_operators: dict[tuple, SchurSpaceMatvec] = {}     # by the spaces' keys
        self._extensions: HarmonicExtensions | None = None  # explicit harmonic extensions (with explicit S)
        self._last_load: _InteriorLoad | None = None

    def _explicit_groups(self) -> list[_SchurGroup]:
        """Subdomains grouped by (template, interior set, interface set): one dense S_t each."""
        sub = self.sub
        groups: dict[bytes, _SchurGroup] = {}
        for s in range(sub.n_sub):
            lo, hi = sub.offsets[s], sub.offsets[s + 1]
            loc = sub.local_index[lo:hi]
            loc_g = loc[self.gamma[lo:hi]]
            if loc_g.size == 0:
                continue
            loc_i = loc[self.interior[lo:hi]]
            t = int(sub.template[s])
            key = (t.to_bytes(8, "little") + loc_i.size.to_bytes(8, "little")
                   + loc_i.astype(np.int64).tobytes() + loc_g.astype(np.int64).tobytes())
            if key not in groups:
                groups[key] = _SchurGroup(template=t, interior_local=loc_i, gamma_local=loc_g, members=[])
            groups[key].members.append(s)
        return list(groups.values())

    def _factor_of(self, group: _SchurGroup):
        """The interior factorization of a group (built by ``self.II``, found in the shared cache)."""
        return self._cache[group.template.to_bytes(8, "little") + group.interior_local.astype(np.int64).tobytes()]

    def _build_explicit(self, force: bool = False) -> DenseBlocks | bool:
        groups = self._explicit_groups()
        biggest = max((g.gamma_local.size for g in groups), default=0)
        explicit = True if force else self._explicit_option
        if explicit is None:
            setup_cols = sum(g.gamma_local.size for g in groups)
            fits = biggest <= EXPLICIT_MAX_BLOCK
            explicit = setup_cols <= EXPLICIT_SETUP_MATVECS * max(self.sub.n_sub, 1) and fits
            if fits and not explicit:                # rent now, buy once the rent has reached the price
                self._switch_after = setup_cols / max(self.sub.n_sub, 1)
        if not explicit:
            return False
        sub = self.sub
        blocks = []
        # the harmonic extensions are kept for interior_solution when chosen at first use (a switch
        # after many implicit applications keeps none: its build must not add memory at the end)
        keep_ext = not force and (sum(g.interior_local.size * g.gamma_local.size for g in groups) * 8
                                  <= EXPLICIT_EXTENSION_BYTES)
        corrections, extensions = self._harmonic_products(groups, keep_ext)
        ext: list[ExtensionBlock] = []
        for k, group in enumerate(groups):
            t, loc_i, loc_g, members = group.template, group.interior_local, group.gamma_local, group.members
            Kg = sub.stiffness[t][loc_g]
            S = Kg[:, loc_g].toarray()
            members_arr = np.asarray(members)
            index = sub.positions(members_arr, loc_g)
            if loc_i.size:
                S -= corrections.pop(k)
                S = 0.5 * (S + S.T)
                if keep_ext:
                    ext.append(ExtensionBlock(np.ascontiguousarray(extensions.pop(k)), index,
                                              sub.positions(members_arr, loc_i)))
            blocks.append((S, index, sub.rho[members_arr]))
        if keep_ext:
            self._extensions = HarmonicExtensions(
                blocks=ext,
                flat_gamma=np.concatenate([e.gamma_index.ravel() for e in ext]) if ext else np.zeros(0, np.int64),
                flat_interior=np.concatenate([e.interior_index.ravel() for e in ext]) if ext else np.zeros(0, np.int64))
        log.debug("DirichletSchur: %d explicit local Schur complements (largest %d)", len(blocks), biggest)
        return DenseBlocks(blocks)

    def _harmonic_products(self, groups: list[_SchurGroup], keep_ext: bool) -> tuple[dict, dict]:
        """K_GI K_II^{-1} K_IG of every group with an interior, shape (n_G, n_G), and, with ``keep_ext``,
        the harmonic extensions X = K_II^{-1} K_IG, shape (n_I, n_G) (rho cancels in both).

        All groups are solved together, column window by column window (:func:`solve_many`: the
        batched subdomains share each solve of their block-diagonal factorization, so a window costs
        its width in whole solves, whichever groups it holds). Kept extensions take one window of
        every column; otherwise a window holds at most ``EXPLICIT_BUILD_BYTES`` of X and is reduced
        to its columns of K_GI X at once (batches of groups instead would pay the whole
        factorization's solves once per batch).
        """
        sub = self.sub
        K_igs = {k: sub.stiffness[g.template][g.interior_local][:, g.gamma_local]
                 for k, g in enumerate(groups) if g.interior_local.size}
        widest = max((K.shape[1] for K in K_igs.values()), default=0)
        rows = sum(K.shape[0] for K in K_igs.values())
        window = max(1, widest if keep_ext else EXPLICIT_BUILD_BYTES // (8 * max(rows, 1)))
        whole = window >= widest                # one window of every column: the dense product, one GEMM
        corrections = {} if whole else {k: np.empty((K.shape[1], K.shape[1])) for k, K in K_igs.items()}
        extensions: dict[int, np.ndarray] = {}
        factors = {k: self._factor_of(groups[k]) for k in K_igs}
        for c0 in range(0, widest, window):
            keys = [k for k, K in K_igs.items() if K.shape[1] > c0]
            columns = [K_igs[k] if whole else K_igs[k][:, c0:c0 + window] for k in keys]
            for k, X in zip(keys, solve_many([(factors[k], K) for k, K in zip(keys, columns)])):
                if whole:
                    corrections[k] = K_igs[k].toarray().T @ X
                    if keep_ext:
                        extensions[k] = X
                else:
                    corrections[k][:, c0:c0 + X.shape[1]] = K_igs[k].T @ X
        return corrections, extensions

    def _interior_load(self, f: np.ndarray) -> np.ndarray:
        """A_II^{-1} f_I (zero off the interior), cached for the last f (same array, same values)."""
        hit = self._last_load
        if hit is not None and hit.source is f and np.array_equal(hit.values, f):
            return hit.solution
        z = self.II.solve(f)
        self._last_load = _InteriorLoad(source=f, values=f.copy(), solution=z)
        return z

    @property
    def extensions(self) -> HarmonicExtensions | None:
        """The explicit harmonic extensions K_II^{-1} K_IG (None: implicit, or over the memory budget)."""
        return self._extensions if self.explicit else None

    @property
    def explicit(self) -> bool:
        """Whether :meth:`matvec` uses explicit local Schur complements (decided on first use)."""
        if self._blocks is None:
            self._blocks = self._build_explicit()
        return self._blocks is not False

    def explicit_blocks(self) -> DenseBlocks:
        """The explicit local Schur complements S_i, formed now if they are not yet (e.g. for
        :func:`ddsolve.dd.deluxe.deluxe_scaling`); later applications use them too."""
        if not self.explicit:               # as explicit=True: one batch of solves, extensions kept in budget
            self._explicit_option, self._switch_after = True, None
            self._blocks = self._build_explicit()
        return self._blocks

    def _use_explicit(self) -> bool:
        """:attr:`explicit` for one application, counting implicit ones and switching to the
        explicit blocks once they have paid off (see the ``explicit`` parameter)."""
        if self.explicit:
            return True
        if self._switch_after is not None:
            self._implicit_applications += 1
            if self._implicit_applications > self._switch_after:
                log.debug("DirichletSchur: explicit local Schur complements formed after %d implicit "
                          "applications", self._implicit_applications - 1)
                self._switch_after = None
                self._blocks = self._build_explicit(force=True)
                return True
        return False

    def space_matvec(self, u, space_in, space_out) -> np.ndarray:
        """gather_out(S scatter_in(u)) between spaces of continuous interface values.

        Parameters
        ----------
        u : ndarray or sequence of ndarray
            Values in ``space_in`` (one array per space if a sequence).
        space_in : space or sequence of spaces
            Objects with ``idx`` (W positions), ``pos`` (compact index of each
            position) and ``n`` (dimension), e.g. the hybrid's ``InterfaceSpace``
            (its ``key``, when present, keys the cache);
            scatter_in puts ``u[pos]`` on every W position ``idx`` (the spaces
            of a sequence must not overlap). Entries must lie on Gamma.
        space_out : space
            gather_out sums the copies of the result on its positions.

        Returns
        -------
        ndarray, shape (space_out.n,)

        Notes
        -----
        With explicit local Schur complements no W vector is formed: only the
        subdomains that touch both spaces are applied, on compact index maps
        built once per (spaces) pair.
        """
        spaces = list(space_in) if isinstance(space_in, (list, tuple)) else [space_in]
        us = list(u) if isinstance(space_in, (list, tuple)) else [u]
        if not self._use_explicit():
            w = np.zeros(self.sub.n_W)
            for sp_, v in zip(spaces, us):
                w[sp_.idx] = v[sp_.pos]
            y = self._implicit_matvec(w)
            return np.bincount(space_out.pos, weights=y[space_out.idx], minlength=space_out.n)
        key = tuple(space_key(x) for x in spaces) + (space_key(space_out),)
        op = self._space_operators.get(key)
        if op is None:
            op = self._space_operators[key] = self._build_space_operator(spaces, space_out)
        return op.apply(us)

    def _build_space_operator(self, spaces, space_out) -> SchurSpaceMatvec:
        n_W = self.sub.n_W
        lin = np.full(n_W, -1, dtype=np.int64)
        off = 0
        for sp_ in spaces:
            lin[sp_.idx] = sp_.pos + off
            off += sp_.n
        lout = np.full(n_W, -1, dtype=np.int64)
        lout[space_out.idx] = space_out.pos
        parts = []
        for A, o, n, n_m, scale in self._blocks.parts:
            index = self._blocks.flat[o:o + n * n_m].reshape(n, n_m)
            keep = (lin[index] >= 0).any(axis=0) & (lout[index] >= 0).any(axis=0)
            if keep.any():
                parts.append((A, index[:, keep], scale[keep]))
        blocks = DenseBlocks(parts)
        cin = lin[blocks.flat]
        cin[cin < 0] = off                      # the zero appended to u
        cout = lout[blocks.flat]
        osel = None if (cout >= 0).all() else np.flatnonzero(cout >= 0)
        return SchurSpaceMatvec(blocks=blocks, index_in=cin, index_out=cout, out_select=osel, n_out=space_out.n)

    def matvec(self, w: np.ndarray) -> np.ndarray:
        """S w for a W vector (read on Gamma); result is zero off Gamma."""
        if self._use_explicit():
            y = np.zeros(self.sub.n_W)
            blocks = self._blocks
            y[blocks.flat] = blocks.apply(w[blocks.flat])
            return y
        return self._implicit_matvec(w)

    def _implicit_matvec(self, w: np.ndarray) -> np.ndarray:
        """S w = K_GG w - K_GI K_II^{-1} K_IG w by two sparse products and one interior solve."""
        w = np.where(self.gamma, w, 0.0)
        t = self.sub.K_W @ w
        z = self.II.solve(t)
        y = t - self.sub.K_W @ z
        return np.where(self.gamma, y, 0.0)

    def harmonic_extension_rhs(self, f: np.ndarray) -> np.ndarray:
        """g = f_Gamma - A_GI A_II^{-1} f_I (condensed load), zero off Gamma."""
        z = self._interior_load(f)
        return np.where(self.gamma, f - self.sub.K_W @ z, 0.0)

    def interior_solution(self, f: np.ndarray, w_gamma: np.ndarray) -> np.ndarray:
        """Complete interface values by u_I = A_II^{-1} (f_I - A_IG w_Gamma); returns a full W vector."""
        w = np.where(self.gamma, w_gamma, 0.0)
        if self.explicit and self._extensions is not None:
            # u_I = A_II^{-1} f_I - (A_II^{-1} A_IG) w_G: the cached interior load and one GEMM per group
            ext = self._extensions
            wg = w[ext.flat_gamma]
            out = np.empty(ext.flat_interior.size)
            og = oi = 0
            for block in ext.blocks:
                n_g, n_m = block.gamma_index.shape
                n_i = block.interior_index.shape[0]
                np.matmul(block.extension, wg[og:og + n_g * n_m].reshape(n_g, n_m),
                          out=out[oi:oi + n_i * n_m].reshape(n_i, n_m))
                og += n_g * n_m
                oi += n_i * n_m
            x = w + self._interior_load(f)
            x[ext.flat_interior] -= out
            return x
        return w + self.II.solve(f - self.sub.K_W @ w)


def space_key(space) -> tuple:
    """Cache key of a space (``idx``, ``pos``, ``n``): its ``key`` attribute, else its index bytes."""
    key = getattr(space, "key", None)
    if key is not None:
        return key
    return (np.asarray(space.idx).tobytes(), np.asarray(space.pos).tobytes(), int(space.n))


class PairJump:
    """A jump operator between pairs of entries of one vector space, given by index arrays.

    Row k of B is ``+c1_k`` at entry ``first[k]`` and ``-c2_k`` at entry ``second[k]``:
    the jump (B u)_k = u_first - u_second (coefficients None), or a scaled jump B_D with
    each copy weighted by the other copy's weight (the delta-dagger / rho scaling of
    Section 2.5 at the level of bodies, ``coef_first`` = weight of the second copy).

    Parameters
    ----------
    first, second : ndarray of int, shape (n_rows,)
        Entry of the first and of the second copy of every pair.
    n : int
        Dimension of the vector space the entries index.
    coef_first, coef_second : ndarray, shape (n_rows,), optional
        Coefficients of the two copies (None: 1).
    """

    def __init__(self, first: np.ndarray, second: np.ndarray, n: int,
                 coef_first: np.ndarray | None = None, coef_second: np.ndarray | None = None) -> None:
        self.first, self.second, self.n = first, second, int(n)
        self.coef_first, self.coef_second = coef_first, coef_second
        self.shape = (first.size, self.n)

    def matvec(self, u: np.ndarray) -> np.ndarray:
        """B u, shape (n,) -> (n_rows,)."""
        if self.coef_first is None:
            return u[self.first] - u[self.second]
        return self.coef_first * u[self.first] - self.coef_second * u[self.second]

    def rmatvec(self, lam: np.ndarray) -> np.ndarray:
        """B^T lam, shape (n_rows,) -> (n,)."""
        if self.coef_first is None:
            return (np.bincount(self.first, weights=lam, minlength=self.n)
                    - np.bincount(self.second, weights=lam, minlength=self.n))
        return (np.bincount(self.first, weights=self.coef_first * lam, minlength=self.n)
                - np.bincount(self.second, weights=self.coef_second * lam, minlength=self.n))


def scaled_jump(B_D, schur):
    """The Dirichlet preconditioner pattern lam -> B_D S B_D^T lam (Section 2.5).

    Used for the FETI/FETI-DP/FETI-FETI preconditioner M_D^{-1} = B_D S B_D^T, the
    multiplier block Z B_{Gamma_OL,D} S~_OL B_{Gamma_OL,D}^T Z of the hybrid's (4.11)
    and the preconditioner B^_D S^_c B^_D^T of the active set method (Chapter 5).

    Parameters
    ----------
    B_D : sparse matrix or :class:`PairJump`, shape (n_lambda, n)
        Scaled jump operator.
    schur : callable
        (n,) -> (n,): the (possibly inexact) Schur complement S.

    Returns
    -------
    callable
        (n_lambda,) -> (n_lambda,).
    """
    if sp.issparse(B_D):
        B_DT = B_D.T.tocsr()

        def apply(lam: np.ndarray) -> np.ndarray:
            return B_D @ schur(B_DT @ lam)
    else:
        def apply(lam: np.ndarray) -> np.ndarray:
            return B_D.matvec(schur(B_D.rmatvec(lam)))
    return apply


def linear_operator(n: int, matvec) -> spla.LinearOperator:
    """Wrap a matvec as a symmetric scipy LinearOperator of shape (n, n)."""
    return spla.LinearOperator((n, n), matvec=matvec, rmatvec=matvec, dtype=float)


# The primal-constrained solver lives in ddsolve.dd.primal (imported last: it reads this module's
# thresholds); its names stay importable from here.
from .primal import (
    CoarseBlock,
    ExplicitInterfaceSolve,
    ExplicitSpaceSolve,
    ImplicitInterfaceSolve,
    ImplicitSpaceSolve,
    InterfaceBlocks,
    InterfaceSolve,
    PrimalConstrainedSolver,
)

__all__ = [
    "EXPLICIT_EXTENSION_BYTES",
    "EXPLICIT_MAX_BLOCK",
    "EXPLICIT_SETUP_MATVECS",
    "CoarseBlock",
    "DirichletSchur",
    "ExplicitInterfaceSolve",
    "ExplicitSpaceSolve",
    "ExtensionBlock",
    "HarmonicExtensions",
    "ImplicitInterfaceSolve",
    "ImplicitSpaceSolve",
    "InterfaceBlocks",
    "InterfaceSolve",
    "PairJump",
    "PrimalConstrainedSolver",
    "SchurSpaceMatvec",
    "linear_operator",
    "scaled_jump",
    "space_key",
]
