"""The global interface between bodies: multipliers B_gl and the active mask Z^k.

Bodies own separate copies of the nodes on their common boundary. Every pair
of copies at one location (fully redundant at cross points where four bodies
meet) gets one global multiplier enforcing u^a - u^b = 0 (Section 3.4). The
active contact area Gamma^k is a boolean mask over these multipliers (the
diagonal of Z_gl^k); it is an *input* of the operators, so changing it never
rebuilds subdomain factorizations.
"""
from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp

from ..dd.substructure import Substructures, rho_powers
from ..errors import InputError

#: Contact areas of problem (4.32).
from ..options import CONTACTS  # noqa: E402

#: The solvability check of G^T lambda = e (G = Z B R, one column per floating body): G^T G must be regular,
#: its smallest eigenvalue above UNTIED_TOL times max(largest, 1); the one message of the methods that check it
#: (the hybrid method, FETI-FETI, the distributed active set method).
UNTIED_TOL = 1e-10
UNTIED_MESSAGE = "G^T G is singular: some floating body is not tied to a clamped body by active multipliers"


class GlobalInterface:
    """Inter-body multipliers of a multibody :class:`Substructures`.

    Parameters
    ----------
    sub : Substructures
        Layout of a scene with several bodies.

    Attributes
    ----------
    mask : ndarray of bool, shape (n_W,)
        W entries on nodes of the global interface (all subdomain copies).
    designated : ndarray of int, shape (n_nodes,)
        For each global-interface node, the W entry through which B_gl acts
        (the first subdomain copy; nodes on the body boundary shared by
        several subdomains are primal vertices, so all copies agree).
    pairs : ndarray of int, shape (n_gl, 2)
        Designated W entries (a, b) of each multiplier, body(a) < body(b).
    bodies : ndarray of int, shape (n_gl, 2)
        Bodies of a and b.
    weight : ndarray, shape (n_W,)
        Body-level delta-dagger of Section 3.4 at each designated entry:
        sum of rho^gamma over the body's subdomains at x, divided by the same
        sum over all bodies at x.
    """

    def __init__(self, sub: Substructures) -> None:
        scene = sub.scene
        self.sub = sub
        loc = scene.locations()
        node_body = np.full(scene.n_nodes, -1)
        node_body[scene.elements.ravel()] = np.repeat(scene.subdomain_body[scene.element_subdomain], scene.elements.shape[1])
        # locations held by more than one body (Dirichlet nodes included: they fix the face geometry)
        nodes = np.flatnonzero(node_body >= 0)
        n_at = np.bincount(loc[nodes], minlength=loc.max() + 1)
        gl_all = nodes[n_at[loc[nodes]] > 1]
        free = ~scene.dirichlet
        gl_nodes = gl_all[free[gl_all]]
        self.mask = np.isin(sub.node_of_W, gl_nodes)

        designated = np.full(scene.n_nodes, -1)
        entries = np.flatnonzero(self.mask)
        # first copy of every node: W entries are ordered by subdomain, keep the first occurrence
        first_nodes, first_idx = np.unique(sub.node_of_W[entries], return_index=True)
        designated[first_nodes] = entries[first_idx]
        self.designated = designated

        if sub.scaling == "multiplicity":
            w = np.ones(sub.n_W)
        else:
            w = rho_powers(sub.rho[sub.sub_of_W], sub.gamma, loc[sub.node_of_W], loc.max() + 1)   # per location
        node_w = np.bincount(sub.node_of_W, weights=w, minlength=scene.n_nodes)
        loc_w = np.bincount(loc, weights=node_w, minlength=loc.max() + 1)
        weight = np.zeros(sub.n_W)
        weight[designated[gl_nodes]] = node_w[gl_nodes] / loc_w[loc[gl_nodes]]
        self.weight = weight

        # fully redundant pairs per location, over all nodes; multipliers only between free copies
        order = gl_all[np.lexsort((node_body[gl_all], loc[gl_all]))]
        lo = loc[order]
        starts = np.flatnonzero(np.r_[True, lo[1:] != lo[:-1]])
        sizes = np.diff(np.r_[starts, lo.size])
        first, second = [], []
        for k in np.unique(sizes):
            for a, b in itertools.combinations(range(int(k)), 2):
                first.append(order[starts[sizes == k] + a])
                second.append(order[starts[sizes == k] + b])
        na = np.concatenate(first) if first else np.zeros(0, dtype=int)
        nb = np.concatenate(second) if second else np.zeros(0, dtype=int)
        srt = np.lexsort((node_body[nb], node_body[na], loc[na]))
        na, nb = na[srt], nb[srt]
        # face extents per body pair from all pairs (Dirichlet ends included)
        body_pairs = np.stack([node_body[na], node_body[nb]], axis=1)
        # one sort for all body pairs (a mask over all pairs per body pair was O(n_bodypairs n_gl); a review)
        self._face_extent: dict[tuple[int, int], tuple[int, float, float]] = {}
        if na.size:
            keys, group = np.unique(body_pairs, axis=0, return_inverse=True)
            group = group.ravel()
            by_group = np.argsort(group, kind="stable")
            starts = np.flatnonzero(np.r_[True, np.diff(group[by_group]) != 0])
            xy = scene.coords[na[by_group]]
            low, high = np.minimum.reduceat(xy, starts, axis=0), np.maximum.reduceat(xy, starts, axis=0)
            extent = high - low
            axis = np.argmax(extent, axis=1)
            rows = np.arange(keys.shape[0])
            for key, ax, lo_, ext in zip(keys.tolist(), axis.tolist(), low[rows, axis].tolist(),
                                         extent[rows, axis].tolist()):
                self._face_extent[(key[0], key[1])] = (ax, lo_, ext)
        keep = free[na] & free[nb]
        na, nb = na[keep], nb[keep]
        self.pair_nodes = np.stack([na, nb], axis=1)
        self.pairs = np.stack([designated[na], designated[nb]], axis=1)
        self.bodies = body_pairs[keep]
        self.n_gl = na.size
        self._coords = scene.coords[na]

    def active_mask(self, active) -> np.ndarray:
        """``active`` as a bool mask of shape (n_gl,), or :class:`~ddsolve.errors.InputError` naming it
        (a mask of another length raised a bare IndexError in the solvers). Integers 0 and 1 are read as
        False and True; any other value is refused (7 was read as True; a review)."""
        mask = np.asarray(active)
        integral = np.issubdtype(mask.dtype, np.integer) and mask.shape == (self.n_gl,)
        if integral and mask.size and (mask.min() < 0 or mask.max() > 1):
            raise InputError("active", f"must be a bool array (or of 0 and 1), got the integer "
                                       f"{int(mask[(mask < 0) | (mask > 1)][0])}")
        if mask.shape != (self.n_gl,) or not (mask.dtype == bool or integral):
            raise InputError("active", f"must be a bool array of shape ({self.n_gl},) (one entry per global "
                                       f"pair), got {mask.dtype} of shape {mask.shape}")
        return mask.astype(bool, copy=False)

    def contact_mask(self, contact: str) -> np.ndarray:
        """Active multipliers of problem (4.32).

        Parameters
        ----------
        contact : {"full", "middle"}
            (I) ``"full"``: the whole inter-body interface, cross points
            included. (II) ``"middle"``: on each face shared by two bodies,
            the nodes whose position along the face lies in the closed middle
            third [L/3, 2L/3] (to 1e-9 L); cross-point pairs between bodies
            that meet only at a corner are inactive.

        Returns
        -------
        ndarray of bool, shape (n_gl,)
        """
        if contact == "full":
            return np.ones(self.n_gl, dtype=bool)
        if contact != "middle":
            raise InputError("contact", f"must be one of {', '.join(CONTACTS)}, got {contact!r}")
        active = np.zeros(self.n_gl, dtype=bool)
        for k in range(self.n_gl):
            axis, start, length = self._face_extent[tuple(self.bodies[k])]
            if length > 0:
                t = (self._coords[k, axis] - start) / length
                active[k] = (t >= 1 / 3 - 1e-9) and (t <= 2 / 3 + 1e-9)
        return active

    def operators(self, active: np.ndarray | None = None) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """B_gl and its scaled version B_gl,D restricted to the active rows (Z^k B_gl).

        Entry of copy a is multiplied by the weight of b's body and vice versa.

        Returns
        -------
        B, B_D : scipy.sparse.csr_matrix, shape (n_active, n_W)
        """
        pairs = self.pairs if active is None else self.pairs[active]
        n = pairs.shape[0]
        rows = np.r_[np.arange(n), np.arange(n)]
        cols = np.r_[pairs[:, 0], pairs[:, 1]]
        B = sp.csr_matrix((np.r_[np.ones(n), -np.ones(n)], (rows, cols)), shape=(n, self.sub.n_W))
        w = self.weight
        B_D = sp.csr_matrix((np.r_[w[pairs[:, 1]], -w[pairs[:, 0]]], (rows, cols)), shape=(n, self.sub.n_W))
        return B, B_D

    def floating_bodies(self) -> np.ndarray:
        """Bodies without Dirichlet nodes, shape (n_floating,)."""
        sub = self.sub
        n_b = sub.scene.n_bodies
        touches = np.zeros(n_b, dtype=bool)
        touches[sub.body_of_sub[~sub.floating_sub]] = True
        return np.flatnonzero(~touches)
