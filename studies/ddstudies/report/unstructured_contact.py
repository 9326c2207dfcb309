"""One unstructured contact solution with its METIS partition.

The two membranes of (3.1) meshed by netgen (P1 triangles, conforming on the
contact line x = 1, split apart into two bodies), each split into METIS
subdomains, solved by one contact method (:func:`ddstudies.report.contact_plots.solve_contact_case`,
the same call as Figure 5.2). :func:`plot_unstructured_contact` draws three panels:

1. the partition: every triangle coloured by its subdomain, the mesh edges thin;
2. the solution u (``tripcolor``, Gouraud shading, with ``tricontour`` lines),
   the subdomain boundaries (edges between triangles of two subdomains) in
   black, and the contact pairs on x = 1 marked: active (lambda > 0) filled red,
   inactive open grey;
3. along the contact line Gamma_c (bottom, the full width): u^1, u^2 and the
   multiplier lambda against y, the active pairs shaded (:func:`ddstudies.report.contact_plots.contact_line`).

Uses the non-interactive Agg backend.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from .contact_plots import _save, _spans, contact_line  # noqa: E402

__all__ = ["MeshSolution", "mesh_solution", "subdomain_boundaries", "plot_unstructured_contact"]


@dataclass(frozen=True)
class MeshSolution:
    """A P1 solution on the scene's mesh, for plotting.

    Attributes
    ----------
    x, y : ndarray, shape (n_nodes,)
        Node coordinates (the contact nodes appear once per body).
    triangles : ndarray of int, shape (n_triangles, 3)
    subdomain : ndarray of int, shape (n_triangles,)
        METIS subdomain of each triangle (body * parts + part).
    u : ndarray, shape (n_nodes,)
        The solution at the nodes (0 on the Dirichlet boundary).
    """

    x: np.ndarray
    y: np.ndarray
    triangles: np.ndarray
    subdomain: np.ndarray
    u: np.ndarray


def mesh_solution(problem: Any, u: np.ndarray) -> MeshSolution:
    """The node values of ``u`` (shape (ndof,), one value per free node copy) on the scene of ``problem``."""
    sub = problem.sub
    scene = sub.scene
    if np.asarray(scene.elements).shape[1] != 3:
        raise ValueError("mesh_solution: the scene is not made of P1 triangles (use mesh 'unstructured')")
    dofs = np.asarray(sub.dof_of_node)
    u = np.asarray(u, dtype=float)
    values = np.where(dofs >= 0, u[np.maximum(dofs, 0)], 0.0)
    return MeshSolution(x=np.asarray(scene.coords[:, 0], dtype=float), y=np.asarray(scene.coords[:, 1], dtype=float),
                        triangles=np.asarray(scene.elements, dtype=np.int64),
                        subdomain=np.asarray(scene.element_subdomain, dtype=np.int64), u=values)


def subdomain_boundaries(triangles: np.ndarray, subdomain: np.ndarray) -> np.ndarray:
    """The edges (pairs of node indices, shape (n, 2)) shared by two triangles of different subdomains.

    One sort of all 3 n_triangles edges (O(n log n)); an edge met twice with two
    subdomains is an interface edge. The contact line is not one: its two sides
    are different nodes (one copy per body).
    """
    triangles = np.asarray(triangles, dtype=np.int64)
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    owner = np.tile(np.asarray(subdomain, dtype=np.int64), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    same = np.all(edges[1:] == edges[:-1], axis=1) & (owner[1:] != owner[:-1])
    return edges[1:][same]


def plot_unstructured_contact(problem: Any, solution: Any, path: str | os.PathLike | None, *,
                              title: str | None = None) -> Any:
    """Partition and solution (top), Gamma_c (bottom): three panels; the figure.

    Parameters
    ----------
    problem : ContactProblem
        Of an unstructured scene (``sub.scene`` with P1 triangles).
    solution : ContactSolution
        ``u``, ``lam``, ``active``.
    path : path-like or None
        PNG to write (nothing when None; the figure stays open).
    title : str, optional
        Figure title.
    """
    mesh = mesh_solution(problem, solution.u)
    line: pd.DataFrame = contact_line(problem, solution)
    fig = plt.figure(figsize=(13, 9.5))
    grid = fig.add_gridspec(2, 2, height_ratios=[1.0, 0.8], width_ratios=[1.0, 1.12])
    ax_part, ax_u, ax_line = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, :])
    n_sub = int(mesh.subdomain.max()) + 1
    # a permutation of the subdomain ids, so that neighbours rarely share a colour of the cyclic map
    colours = np.random.default_rng(0).permutation(n_sub)[mesh.subdomain] % 20
    ax_part.tripcolor(mesh.x, mesh.y, mesh.triangles, facecolors=colours.astype(float), cmap="tab20",
                      vmin=0, vmax=19, edgecolors="white", linewidth=0.15)
    ax_part.set_title(f"METIS partition: {n_sub} subdomains, {len(mesh.triangles):,} triangles")
    tpc = ax_u.tripcolor(mesh.x, mesh.y, mesh.triangles, mesh.u, shading="gouraud", cmap="viridis")
    ax_u.tricontour(mesh.x, mesh.y, mesh.triangles, mesh.u, levels=12, colors="white", linewidths=0.4, alpha=0.6)
    fig.colorbar(tpc, ax=ax_u, fraction=0.03, pad=0.02, label="u")
    edges = subdomain_boundaries(mesh.triangles, mesh.subdomain)
    from matplotlib.collections import LineCollection

    segments = np.stack([np.column_stack([mesh.x[edges[:, k]], mesh.y[edges[:, k]]]) for k in (0, 1)], axis=1)
    ax_u.add_collection(LineCollection(segments, colors="black", linewidths=0.8))
    active = line["active"].to_numpy(dtype=bool)
    x_c = np.ones(len(line))
    ax_u.axvline(1.0, color="white", lw=0.8, ls="--")
    ax_u.plot(x_c[~active], line["y"][~active], "o", mfc="none", mec="0.5", ms=3.5, label="inactive pair")
    ax_u.plot(x_c[active], line["y"][active], "o", color="red", ms=3.5, label="active pair (lambda > 0)")
    ax_u.legend(fontsize=8, loc="lower left")
    ax_u.set_title("u, subdomain boundaries, contact line x = 1")
    for ax in (ax_part, ax_u):
        ax.set_aspect("equal")
        ax.set_xlim(mesh.x.min() - 0.02, mesh.x.max() + 0.02)
        ax.set_ylim(mesh.y.min() - 0.02, mesh.y.max() + 0.02)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    y = line["y"].to_numpy(dtype=float)
    for lo, hi in _spans(y, active):
        ax_line.axvspan(lo, hi, color="tab:red", alpha=0.12, lw=0)
    ax_line.plot(y, line["u1"], "-", color="tab:blue", label="$u^1$ (x = 1, $\\Omega^1$)")
    ax_line.plot(y, line["u2"], "--", color="tab:orange", label="$u^2$ (x = 1, $\\Omega^2$)")
    ax_line.set_xlabel("y on $\\Gamma_c$")
    ax_line.set_ylabel("u")
    twin = ax_line.twinx()
    twin.plot(y, line["lam"], ".", color="tab:red", ms=4, label="$\\lambda$")
    twin.set_ylabel("$\\lambda$ (nodal force, not a pressure)")     # as Figure 5.2's: it scales with the spacing
    handles = ax_line.get_legend_handles_labels()
    more = twin.get_legend_handles_labels()
    ax_line.legend(handles[0] + more[0], handles[1] + more[1], fontsize=8, loc="best")
    ax_line.set_title(f"$\\Gamma_c$: {int(active.sum())} of {len(line)} pairs active (shaded)")
    ax_line.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    if path is not None:
        _save(fig, path)
    return fig
