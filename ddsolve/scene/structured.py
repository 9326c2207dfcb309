"""Structured scenes of the thesis: the unit square split into bodies and subdomains.

The unit square is split into N_b x N_b square bodies (1/H_b = N_b), each body
into N_s x N_s square subdomains (H_b/H_s = N_s), each subdomain into m x m Q1
elements (H_s/h = m); see Sections 4.4 and 5 of the thesis.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .scene import RightHandSide, Scene


def checkerboard(grid: np.ndarray, value: float) -> np.ndarray:
    """rho alternating between 1 and ``value`` like the colours of a chess board.

    Parameters
    ----------
    grid : ndarray of int, shape (n, 2)
        (column, row) of each subdomain.
    value : float
        Coefficient on the 'black' squares ((column + row) odd).

    Returns
    -------
    ndarray, shape (n,)
    """
    return np.where((grid[:, 0] + grid[:, 1]) % 2 == 1, float(value), 1.0)


def structured_square(bodies: int, subdomains: int, elements: int, *,
                      rho: np.ndarray | float = 1.0, f: RightHandSide = 1.0,
                      dirichlet: str = "boundary") -> Scene:
    """Build the structured scene of the unit square.

    Parameters
    ----------
    bodies : int
        Bodies per side N_b = 1/H_b.
    subdomains : int
        Subdomains per body side N_s = H_b/H_s.
    elements : int
        Elements per subdomain side m = H_s/h.
    rho : float or ndarray, shape (N_b^2 N_s^2,)
        Coefficient per subdomain (subdomains numbered body by body, row by row).
    f : float or callable
        Right-hand side.
    dirichlet : {"boundary"}
        u = 0 on the whole outer boundary of the unit square.

    Returns
    -------
    Scene
        Node ids are numbered body by body, row by row within a body. Nodes on
        interfaces between bodies are duplicated, one copy per body, and listed
        in ``contact_pairs``.
    """
    for name, value in (("bodies", bodies), ("subdomains", subdomains), ("elements", elements)):
        if int(value) != value or value < 1:
            raise InputError(name, f"must be a positive integer, got {value!r}")
    if dirichlet != "boundary":
        raise InputError("dirichlet", f"unknown Dirichlet boundary {dirichlet!r}")
    nb, ns, m = int(bodies), int(subdomains), int(elements)
    return body_grid(nb, nb, ns, m, h=1.0 / (nb * ns * m), rho=rho, f=f,
                     dirichlet_sides=("left", "right", "bottom", "top"))


def body_grid(nbx: int, nby: int, ns: int, m: int, *, h: float, rho: np.ndarray | float = 1.0,
              f: RightHandSide = 1.0, dirichlet_sides: tuple[str, ...] = ()) -> Scene:
    """A rectangle of nbx x nby square bodies of side ns*m*h, each of ns x ns subdomains.

    Parameters
    ----------
    nbx, nby : int
        Bodies along x and y; body b = by * nbx + bx has its lower-left corner
        at (bx, by) * ns * m * h.
    ns, m : int
        Subdomains per body side and Q1 elements per subdomain side.
    h : float
        Element side length.
    rho : float or ndarray, shape (nbx nby ns^2,)
        Coefficient per subdomain (subdomains numbered body by body, row by row).
    f : float, callable or ndarray of shape (n_elements,)
        Right-hand side.
    dirichlet_sides : tuple of {"left", "right", "bottom", "top"}
        Sides of the rectangle on which u = 0.

    Returns
    -------
    Scene
        Node ids are numbered body by body, row by row within a body. Nodes on
        interfaces between bodies are duplicated, one copy per body, and listed
        in ``contact_pairs`` (a in the lower-numbered body).
    """
    unknown = set(dirichlet_sides) - {"left", "right", "bottom", "top"}
    if unknown:
        raise InputError("dirichlet", f"unknown sides {sorted(unknown)}")
    n = ns * m                      # elements per body side
    npb = (n + 1) ** 2              # nodes per body

    # Nodes of one body, row-major, then shifted per body.
    iy, ix = np.divmod(np.arange(npb), n + 1)
    coords, dir_mask, elems, el_sub = [], [], [], []
    # Elements of one body: lower-left node id, then CCW.
    ey, ex = np.divmod(np.arange(n * n), n)
    ll = ey * (n + 1) + ex
    quad = np.stack([ll, ll + 1, ll + n + 2, ll + n + 1], axis=1)
    sub_local = (ey // m) * ns + (ex // m)
    grid = []
    for by in range(nby):
        for bx in range(nbx):
            b = by * nbx + bx
            coords.append(np.stack([(bx * n + ix) * h, (by * n + iy) * h], axis=1))
            on_boundary = np.zeros(npb, dtype=bool)
            if "left" in dirichlet_sides:
                on_boundary |= (bx == 0) & (ix == 0)
            if "right" in dirichlet_sides:
                on_boundary |= (bx == nbx - 1) & (ix == n)
            if "bottom" in dirichlet_sides:
                on_boundary |= (by == 0) & (iy == 0)
            if "top" in dirichlet_sides:
                on_boundary |= (by == nby - 1) & (iy == n)
            dir_mask.append(on_boundary)
            elems.append(quad + b * npb)
            el_sub.append(sub_local + b * ns * ns)
            sy, sx = np.divmod(np.arange(ns * ns), ns)
            grid.append(np.stack([bx * ns + sx, by * ns + sy], axis=1))
    coords = np.concatenate(coords)
    grid = np.concatenate(grid)
    n_sub = nbx * nby * ns * ns
    rho_arr = np.broadcast_to(np.asarray(rho, dtype=float), (n_sub,)).copy()
    if np.any(~np.isfinite(rho_arr)) or np.any(rho_arr <= 0):
        raise InputError("rho", "must be positive on every subdomain")

    # Matching node pairs across body interfaces (vertical then horizontal faces).
    pairs = []
    k = np.arange(n + 1)
    for by in range(nby):
        for bx in range(nbx):
            b = by * nbx + bx
            if bx + 1 < nbx:   # right face of b against left face of b+1
                pairs.append(np.stack([b * npb + k * (n + 1) + n, (b + 1) * npb + k * (n + 1)], axis=1))
            if by + 1 < nby:   # top face of b against bottom face of b+nbx
                pairs.append(np.stack([b * npb + n * (n + 1) + k, (b + nbx) * npb + k], axis=1))
    contact_pairs = np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=np.int64)

    return Scene(coords=coords, elements=np.concatenate(elems),
                 element_subdomain=np.concatenate(el_sub),
                 subdomain_body=np.repeat(np.arange(nbx * nby), ns * ns),
                 rho=rho_arr, dirichlet=np.concatenate(dir_mask), f=f,
                 subdomain_grid=grid, contact_pairs=contact_pairs)
