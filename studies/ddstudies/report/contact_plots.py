"""Plots of the contact problem (3.1): Figure 5.2 and the method comparison of Tables 5.1 / 6.1.

- :func:`solve_contact_case` solves one spec and keeps the problem data the
  plots need (the node geometry, the contact pairs), which :func:`ddsolve.solve`
  does not return.
- :func:`membrane_surfaces` and :func:`plot_membranes` draw the solution on
  both membranes as 3D surfaces seen from two angles (Figure 5.2 of the
  thesis: N_sub = 16, H/h = 8).
- :func:`contact_line` and :func:`plot_contact_line` show u^1, u^2 and lambda
  along Gamma_c = {1} x [0, 1] against y, with the contact zone (the active
  pairs, lambda > 0) shaded.
- :func:`plot_method_comparison` draws the total iterations and wall times of
  :func:`ddstudies.report.contact_tables.method_comparison` per grid.

Uses the non-interactive Agg backend.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from .plots import _save  # noqa: E402  (atomic, as every figure of the report)

log = logging.getLogger(__name__)

__all__ = ["MembraneSurface", "solve_contact_case", "membrane_surfaces", "contact_line",
           "plot_membranes", "plot_contact_line", "plot_method_comparison"]




def solve_contact_case(spec: Any) -> tuple[Any, Any]:
    """Solve one contact spec and return the assembled problem with the solution.

    Parameters
    ----------
    spec : ProblemSpec or mapping
        A spec with ``problem="contact"`` (e.g. ``{"problem": "contact", "method":
        "active-set", "subdomains": 4, "elements": 8}``).

    Returns
    -------
    problem : ddsolve.contact.ContactProblem
        Its ``sub.scene`` holds the node coordinates, ``y`` the pair positions.
    solution : ddsolve.contact.ContactSolution
        ``u`` (shape (ndof,)), ``lam`` and ``active`` (shape (n_c,)).
    """
    from threadpoolctl import threadpool_limits

    from ddsolve.contact.run import run_contact_method
    from ddsolve.prepared import prepare
    from ddsolve.spec import ProblemSpec

    if not isinstance(spec, ProblemSpec):
        spec = ProblemSpec.from_mapping(dict(spec))
    if spec.problem != "contact":
        raise ValueError(f"solve_contact_case: problem must be 'contact', got {spec.problem!r}")
    with threadpool_limits(limits=1, user_api="blas"):
        problem = prepare(spec).contact
        solution = run_contact_method(spec.method, problem, rtol=float(spec.rtol), maxiter=int(spec.maxiter))
    log.info("contact %s N=%d H/h=%d: %s", spec.method, spec.subdomains, spec.elements, solution.reason)
    return problem, solution


@dataclass
class MembraneSurface:
    """The solution on one membrane, ready for ``plot_trisurf``.

    Attributes
    ----------
    body : int
        0 for Omega^1 = (0, 1)^2, 1 for Omega^2 = (1, 2) x (0, 1).
    x, y, u : ndarray, shape (n_nodes,)
        Node coordinates and values (0 on the clamped edge).
    triangles : ndarray of int, shape (2 n_elements, 3)
        Each Q1 element split into two triangles, local node numbers.
    """

    body: int
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    triangles: np.ndarray


def membrane_surfaces(problem: Any, u: np.ndarray) -> list[MembraneSurface]:
    """Split a solution of (3.1) into the two membranes.

    Parameters
    ----------
    problem : ContactProblem
    u : ndarray, shape (ndof,)
        Displacements (one value per body copy of the contact nodes).

    Returns
    -------
    list of MembraneSurface
        One per body, in body order.
    """
    sub = problem.sub
    scene = sub.scene
    u = np.asarray(u, dtype=float)
    dofs = np.asarray(sub.dof_of_node)
    values = np.where(dofs >= 0, u[np.maximum(dofs, 0)], 0.0)
    element_body = np.asarray(scene.subdomain_body)[np.asarray(scene.element_subdomain)]
    out = []
    for body in range(int(scene.n_bodies)):
        elements = np.asarray(scene.elements)[element_body == body]
        nodes = np.unique(elements)
        local = np.full(scene.coords.shape[0], -1, dtype=np.int64)
        local[nodes] = np.arange(nodes.size)
        quads = local[elements]
        triangles = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        out.append(MembraneSurface(body, scene.coords[nodes, 0].copy(), scene.coords[nodes, 1].copy(),
                                   values[nodes], triangles))
    return out


def contact_line(problem: Any, solution: Any) -> pd.DataFrame:
    """u^1, u^2 and lambda along Gamma_c, one row per contact pair, ordered by y.

    Parameters
    ----------
    problem : ContactProblem
    solution : ContactSolution

    Returns
    -------
    DataFrame
        Columns ``y``, ``u1`` (Omega^1 side), ``u2`` (Omega^2 side), ``gap`` =
        u^2 - u^1 (>= 0 when feasible), ``lam`` (the nodal contact multiplier: a force per node, not a
        pressure; at y = 0, whose node has half the support, about half its neighbour's) and
        ``active`` (the solver's final active set).
    """
    u = np.asarray(solution.u, dtype=float)
    dofs = np.asarray(problem.pair_dofs)
    frame = pd.DataFrame({
        "y": np.asarray(problem.y, dtype=float),
        "u1": u[dofs[:, 0]],
        "u2": u[dofs[:, 1]],
        "lam": np.asarray(solution.lam, dtype=float),
        "active": np.asarray(solution.active, dtype=bool),
    })
    frame.insert(3, "gap", frame["u2"] - frame["u1"])
    return frame.sort_values("y", kind="stable").reset_index(drop=True)


def plot_membranes(surfaces: Sequence[MembraneSurface], path: str | os.PathLike, *,
                   views: Sequence[tuple[float, float]] = ((25.0, -60.0), (20.0, 35.0)),
                   title: str | None = None) -> Path:
    """3D surfaces of the solution on both membranes, one panel per view angle (Figure 5.2).

    Parameters
    ----------
    surfaces : sequence of MembraneSurface
        From :func:`membrane_surfaces`.
    path : path-like
        Output PNG.
    views : sequence of (elevation, azimuth)
        Camera angles in degrees, one panel each.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
        The written file.
    """
    fig = plt.figure(figsize=(5.5 * len(views), 4.8))
    cmaps = ("Blues_r", "Oranges_r")
    lo = min(float(s.u.min()) for s in surfaces)
    hi = max(float(s.u.max()) for s in surfaces)
    for k, (elev, azim) in enumerate(views, start=1):
        ax = fig.add_subplot(1, len(views), k, projection="3d")
        for s in surfaces:
            ax.plot_trisurf(s.x, s.y, s.triangles, s.u, cmap=cmaps[s.body % 2], vmin=lo, vmax=hi,
                            linewidth=0.1, edgecolor="0.35", antialiased=True, alpha=0.95)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("u")
        x_lo = min(float(s.x.min()) for s in surfaces)
        x_hi = max(float(s.x.max()) for s in surfaces)
        ax.set_xticks(np.linspace(x_lo, x_hi, 5))          # 9 default ticks overlapped at a flat azimuth
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(f"elevation {elev:g}°, azimuth {azim:g}°", fontsize=9)
    fig.suptitle(title or r"Solution of (3.1) on $\Omega^1$ (blue) and $\Omega^2$ (orange)")
    fig.text(0.5, 0.01, r"$\Omega^1$: blue, $\Omega^2$: orange", ha="center", fontsize=9)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    return _save(fig, path)


def _spans(y: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """Closed y-intervals covering the runs of consecutive True entries (half a spacing beyond)."""
    spans = []
    spacing = float(np.min(np.diff(y))) if y.size > 1 else 1.0
    start = None
    for i, flag in enumerate(mask):
        if flag and start is None:
            start = i
        if start is not None and (not flag or i == mask.size - 1):
            stop = i if flag else i - 1
            spans.append((max(float(y[start]) - spacing / 2, float(y[0])),
                          min(float(y[stop]) + spacing / 2, float(y[-1]))))
            start = None
    return spans


def plot_contact_line(line: pd.DataFrame, path: str | os.PathLike, *, title: str | None = None) -> Path:
    """u^1, u^2 (left axis) and lambda (right axis) against y on Gamma_c, contact zone shaded.

    Parameters
    ----------
    line : DataFrame
        From :func:`contact_line` (columns ``y``, ``u1``, ``u2``, ``lam``, ``active``).
    path : path-like
        Output PNG.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
        The written file.
    """
    y = line["y"].to_numpy(dtype=float)
    active = line["active"].to_numpy(dtype=bool)
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for k, (a, b) in enumerate(_spans(y, active)):
        ax.axvspan(a, b, color="0.88", zorder=0, label="contact zone (active pairs)" if k == 0 else None)
    ax.plot(y, line["u1"], "-", color="tab:blue", lw=1.6, label=r"$u^1(1, y)$")
    ax.plot(y, line["u2"], "--", color="tab:orange", lw=1.6, label=r"$u^2(1, y)$")
    ax.plot(y[active], line["u1"].to_numpy()[active], "|", color="k", ms=6, label="active pair")
    ax.set_xlabel(r"$y$ on $\Gamma_c = \{1\} \times [0, 1]$")
    ax.set_ylabel("displacement")
    ax.set_xlim(float(y[0]), float(y[-1]))
    ax2 = ax.twinx()
    ax2.plot(y, line["lam"], ".-", color="tab:green", lw=1.0, ms=4, label=r"$\lambda$ (nodal contact multiplier)")
    ax2.set_ylabel(r"$\lambda$ (nodal force, not a pressure)", color="tab:green")
    ax2.tick_params(axis="y", colors="tab:green")
    ax2.set_ylim(bottom=min(0.0, float(line["lam"].min())))
    handles = ax.get_legend_handles_labels()
    handles2 = ax2.get_legend_handles_labels()
    ax.legend(handles[0] + handles2[0], handles[1] + handles2[1], loc="lower left", fontsize=8)
    n_active = int(active.sum())
    ax.set_title(title or f"Contact interface: {n_active} of {active.size} pairs active", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def plot_method_comparison(comparison: pd.DataFrame, path: str | os.PathLike, *,
                           caption: str | None = None, rule_set: str | None = None,
                           methods: Sequence[str] = ("active set", "SMALBE"),
                           colors: Mapping[str, str] | None = None) -> Path:
    """Total iterations and wall time per grid, both methods side by side (grouped bars).

    Parameters
    ----------
    comparison : DataFrame
        From :func:`ddstudies.report.contact_tables.method_comparison` (index
        (N_sub(1/H), H/h); columns ``("total it.", label)``, ``("total it.",
        label + " printed")``, ``("wall time [s]", label)``).
    path : path-like
        Output PNG.
    caption : str, optional
        Text under the figure (e.g. :func:`~ddstudies.report.contact_tables.comparison_caption`).
    rule_set : str, optional
        The rule set of the runs, named in the title (where a study ran several, or another than the default).
    methods : sequence of str
        Method labels (second level of the columns).
    colors : mapping, optional
        Color per method label.

    Returns
    -------
    Path
        The written file.
    """
    colors = dict(colors or {"active set": "tab:blue", "SMALBE": "tab:orange"})
    labels = [f"{n}\n{m}" for n, m in comparison.index]
    x = np.arange(len(labels))
    width = 0.8 / max(len(methods), 1)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(max(8.0, 0.45 * len(labels) + 2), 7.5), sharex=True)
    for k, m in enumerate(methods):
        offset = (k - (len(methods) - 1) / 2) * width
        color = colors.get(m)
        if ("total it.", m) in comparison.columns:
            vals = pd.to_numeric(comparison[("total it.", m)], errors="coerce").astype(float)
            ax1.bar(x + offset, vals, width, color=color, label=f"{m} (ours)")
        if ("total it.", f"{m} printed") in comparison.columns:
            ref = pd.to_numeric(comparison[("total it.", f"{m} printed")], errors="coerce").astype(float)
            ax1.plot(x + offset, ref, "o", mfc="none", mec=color, mew=1.5, ms=6, ls="none",
                     label=f"{m} (printed in the thesis)")
        if ("wall time [s]", m) in comparison.columns:
            secs = pd.to_numeric(comparison[("wall time [s]", m)], errors="coerce").astype(float)
            ax2.bar(x + offset, secs, width, color=color, label=m)
    ax1.set_ylabel("total iterations")
    ax1.legend(fontsize=8, ncol=2)
    ax2.set_ylabel("wall time [s] (setup + solve)")
    ax2.set_yscale("log")
    ax2.legend(fontsize=8)
    ax2.set_xticks(x)
    ax2.set_xticklabels(labels, fontsize=7)
    ax2.set_xlabel(r"grid: $N_{sub}(1/H)$ / $H/h$")
    ax1.set_title("Contact problem (3.1): active set + hybrid vs SMALBE, per grid"
                  + (f" (rule set {rule_set})" if rule_set else ""))
    if caption:
        fig.text(0.01, 0.005, caption, fontsize=7, wrap=True, va="bottom")
        fig.tight_layout(rect=(0, 0.035, 1, 1))
    else:
        fig.tight_layout()
    return _save(fig, path)
