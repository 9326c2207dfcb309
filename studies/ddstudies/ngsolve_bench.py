"""Benchmark of DDInverse against NGSolve's own solvers (study kind ``ngsolve``).

Problem: -div((1 + x) grad u) = 1 on the unit square, u = 0 on the boundary,
scalar H1 of order p. For each order and size, every solver starts from the
same *unassembled* BilinearForm and the timings are those a user pays:

* ``ddinverse-bddc`` / ``ddinverse-fetidp``: ``DDInverse(a)`` (broken assembly,
  partition, factorizations) + one solve;
* ``ngs-bddc-cg``: ``Preconditioner(a, "bddc")`` + ``a.Assemble()`` + CGSolver;
* ``ngs-h1amg-cg``: ``Preconditioner(a, "h1amg")`` (order 1) or ``"bddc"`` with
  ``coarsetype="h1amg"`` (order >= 2) + assembly + CGSolver;
* ``sparsecholesky``, ``pardiso``: assembly + ``a.mat.Inverse(freedofs, inverse=...)`` + solve.

All run in one process (one Snakemake job), one after another, with one
thread each; the load average is recorded with every row. Errors of the
reference solution (``sparsecholesky`` where run) are reported per row.

Run: ``python -m ddstudies.ngsolve_bench CONFIG.json OUT.csv OUT.md OUT.png``; the iterations
against the number of parts on one mesh:
``python -m ddstudies.ngsolve_bench --parts-sweep ORDER NDOF 64,256,1024`` (a markdown table); the
condition numbers against H/h at a fixed coarse partition, per order (:func:`hh_study`):
``python -m ddstudies.ngsolve_bench --hh-study 1,2,3,4 PARTS 0,1,2,3 [DIM MAXH [PRIMAL]]`` (a markdown table;
DIM 3: the unit cube; PRIMAL ``vertices+edges``: edge averages); the same
problem on the unit cube (3D, tetrahedra; :func:`cube_study`):
``python -m ddstudies.ngsolve_bench --cube-study 1,2,3 250000 [DOFS_PER_PART]`` (a markdown table).
"""
from __future__ import annotations

import csv
import json
import logging
import math
import os
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

SOLVERS = ("ddinverse-bddc", "ddinverse-fetidp", "ngs-bddc-cg", "ngs-h1amg-cg", "sparsecholesky", "pardiso")


@dataclass
class Row:
    solver: str
    order: int
    ndof: int
    parts: int
    setup_s: float
    solve_s: float
    total_s: float
    iterations: int
    relerr: float
    load: float
    error: str = ""


def make_mesh(order: int, ndof: int):
    """Unit-square mesh with about ``ndof`` H1 dofs of order ``order`` (netgen mesh + uniform refinements)."""
    import ngsolve as ngs
    from netgen.geom2d import unit_square

    nv = ndof / order ** 2
    refine = max(0, math.floor(math.log(max(nv / 4000.0, 1.0), 4)))
    h = math.sqrt(1.17 / (nv / 4 ** refine))
    ngmesh = unit_square.GenerateMesh(maxh=h)
    for _ in range(refine):
        ngmesh.Refine()
    return ngs.Mesh(ngmesh)


def make_cube_mesh(order: int, ndof: int):
    """Unit-cube tetrahedral mesh with about ``ndof`` H1 dofs of order ``order``.

    A netgen mesh of about ``ndof / order^3`` vertices (an order-p space has about p^3 dofs per
    vertex on tetrahedra; netgen gives about 1 / maxh^3 vertices in the unit cube), made with
    ``mesh.Refine()`` (8x the vertices each) from a mesh of at most 40,000 vertices, since
    netgen's 3D mesher is slow.
    """
    import ngsolve as ngs
    from netgen.csg import unit_cube

    nv = max(ndof / order ** 3, 64.0)
    refine = max(0, math.ceil(math.log(max(nv / 40000.0, 1.0), 8)))
    h = (nv / 8 ** refine) ** (-1.0 / 3.0)
    mesh = ngs.Mesh(unit_cube.GenerateMesh(maxh=h))
    for _ in range(refine):
        mesh.Refine()
    return mesh


def _forms(mesh, order):
    import ngsolve as ngs

    fes = ngs.H1(mesh, order=order, dirichlet=".*")
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += (1 + ngs.x) * ngs.grad(u) * ngs.grad(v) * ngs.dx
    f = ngs.LinearForm(fes)
    f += v * ngs.dx
    f.Assemble()
    return fes, a, f


def run_solver(name: str, mesh, order: int, parts: int, rtol: float, maxiter: int):
    """(setup seconds, solve seconds, iterations, solution array) of one solver."""
    import ngsolve as ngs
    from ngsolve.krylovspace import CGSolver

    fes, a, f = _forms(mesh, order)
    gfu = ngs.GridFunction(fes)
    t0 = time.perf_counter()
    its = 0
    if name.startswith("ddinverse-"):
        from ddsolve.ngsolve import DDInverse

        method, _, variant = name.split("-", 1)[1].partition("-")      # ddinverse-fetidp-edges: edge averages
        inv = DDInverse(a, method=method, parts=parts, rtol=rtol, maxiter=maxiter,
                        primal="vertices+edges" if variant == "edges" else "vertices")
        t1 = time.perf_counter()
        gfu.vec.data = inv * f.vec
        its = inv.iterations
    elif name in ("ngs-bddc-cg", "ngs-h1amg-cg"):
        if name == "ngs-bddc-cg":
            pre = ngs.Preconditioner(a, "bddc")
        elif order == 1:
            pre = ngs.Preconditioner(a, "h1amg")
        else:
            pre = ngs.Preconditioner(a, "bddc", coarsetype="h1amg")
        a.Assemble()
        t1 = time.perf_counter()
        solver = CGSolver(a.mat, pre.mat, tol=rtol, maxiter=maxiter)
        gfu.vec.data = solver * f.vec
        its = solver.iterations
    else:
        a.Assemble()
        inv = a.mat.Inverse(fes.FreeDofs(), inverse=name)
        t1 = time.perf_counter()
        gfu.vec.data = inv * f.vec
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1, its, gfu.vec.FV().NumPy().copy()


def run_study(cfg: dict, mesh_of=None) -> list[Row]:
    """Rows of every solver for every (order, ndof) of ``cfg["orders"]``; ``mesh_of(order, ndof)``
    builds the mesh (default :func:`make_mesh`, the unit square)."""
    mesh_of = make_mesh if mesh_of is None else mesh_of
    rows: list[Row] = []
    solvers = cfg.get("solvers", list(SOLVERS))
    for order_cfg in cfg["orders"]:
        order = int(order_cfg["order"])
        for ndof in order_cfg["ndofs"]:
            mesh = mesh_of(order, int(ndof))
            parts = max(2, round(int(ndof) / int(cfg["dofs_per_part"])))
            ref = None
            results = []
            for name in solvers:
                try:
                    s, t, its, x = run_solver(name, mesh, order, parts, float(cfg["rtol"]), int(cfg["maxiter"]))
                    if name == "sparsecholesky":
                        ref = x
                    results.append((name, s, t, its, x, ""))
                except Exception as exc:  # noqa: BLE001  (a missing backend, e.g. pardiso, is reported, not fatal)
                    results.append((name, math.nan, math.nan, 0, None, f"{type(exc).__name__}: {exc}"[:120]))
                log.info("order %d ndof %s %s done", order, ndof, name)
            n = int(np.asarray(results[0][4]).size) if results[0][4] is not None else int(ndof)
            for name, s, t, its, x, err in results:
                rel = (float(np.linalg.norm(x - ref) / np.linalg.norm(ref))
                       if (x is not None and ref is not None) else math.nan)
                rows.append(Row(name, order, n, parts if name.startswith("ddinverse") else 0, s, t, s + t, its,
                                rel, os.getloadavg()[0], err))
    for sweep in cfg.get("parts_sweep", []) if mesh_of is make_mesh else []:
        rows += parts_sweep(int(sweep["order"]), int(sweep["ndof"]), [int(p) for p in sweep["parts"]],
                            float(cfg["rtol"]), maxiter=int(cfg["maxiter"]))
    return rows


def rows_table(rows: list[Row]) -> list[str]:
    """Markdown lines of a table of rows (one per solver and case)."""
    lines = ["| solver | order | ndof | parts | setup s | solve s | total s | its | rel. error | load |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r.solver} | {r.order} | {r.ndof} | {r.parts} | {r.setup_s:.2f} | {r.solve_s:.2f} | "
                     f"{r.total_s:.2f} | {r.iterations} | {r.relerr:.1e} | {r.load:.1f} |"
                     + (f" {r.error}" if r.error else ""))
    return lines


def summary(rows: list[Row]) -> str:
    """Markdown table and the target checks of the issue (reported, not tuned for)."""
    lines = rows_table(rows)
    lines += ["", "Targets:"]
    by = {(r.solver, r.order, r.ndof): r for r in rows}
    for order in sorted({r.order for r in rows}):
        n = max(r.ndof for r in rows if r.order == order and not r.solver.endswith("sweep"))
        dd = by.get(("ddinverse-bddc", order, n))
        if dd is None:
            continue
        if order == 1:
            direct = [by[(s, 1, n)].total_s for s in ("sparsecholesky", "pardiso")
                      if (s, 1, n) in by and math.isfinite(by[(s, 1, n)].total_s)]
            if direct:
                ratio = dd.total_s / min(direct)
                lines.append(f"- order 1, {n} dofs: DDInverse / (assembly + fastest direct) = {ratio:.2f} "
                             f"(target <= 0.5: {'met' if ratio <= 0.5 else 'NOT met'})")
        elif ("ngs-bddc-cg", order, n) in by:
            ratio = dd.total_s / by[("ngs-bddc-cg", order, n)].total_s
            lines.append(f"- order {order}, {n} dofs: DDInverse / NGSolve bddc+CG = {ratio:.2f} "
                         f"(target <= 1.0: {'met' if ratio <= 1.0 else 'NOT met'})")
    sweep = [r for r in rows if r.solver == "ddinverse-bddc-sweep"]
    if len(sweep) >= 2:
        growth = sweep[-1].iterations / max(sweep[0].iterations, 1)
        lines.append(f"- iterations {sweep[0].parts} -> {sweep[-1].parts} parts: {sweep[0].iterations} -> "
                     f"{sweep[-1].iterations} ({growth:.2f}x; target <= 1.3x: {'met' if growth <= 1.3 else 'NOT met'})")
    return "\n".join(lines) + "\n"


def plot(rows: list[Row], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    orders = sorted({r.order for r in rows if not r.solver.endswith("sweep")})
    fig, axes = plt.subplots(1, len(orders), figsize=(4 * len(orders), 3.5), squeeze=False)
    for ax, order in zip(axes[0], orders):
        for name in SOLVERS:
            pts = sorted((r.ndof, r.total_s) for r in rows if r.solver == name and r.order == order
                         and math.isfinite(r.total_s))
            if pts:
                ax.loglog(*zip(*pts), "o-", label=name)
        ax.set_title(f"order {order}")
        ax.set_xlabel("dofs")
        ax.set_ylabel("setup + solve [s]")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    tmp = path + ".tmp.png"
    fig.savefig(tmp, dpi=120)
    os.replace(tmp, path)


def _write_atomic(path: str, text: str) -> None:
    tmp = path + ".tmp"
    Path(tmp).write_text(text)
    os.replace(tmp, path)


def parts_sweep(order: int, ndof: int, parts: list[int], rtol: float = 1e-8, method: str = "bddc",
                maxiter: int = 1000) -> list[Row]:
    """DDInverse iterations on one mesh (about ``ndof`` dofs of order ``order``) for each METIS part count;
    each row's ``ndof`` is the mesh's own (not the requested ``ndof``)."""
    mesh = make_mesh(order, ndof)
    rows = []
    for p in parts:
        s, t, its, x = run_solver(f"ddinverse-{method}", mesh, order, int(p), rtol, maxiter)
        rows.append(Row(f"ddinverse-{method}-sweep", order, int(np.asarray(x).size), int(p), s, t, s + t, its,
                        math.nan, os.getloadavg()[0]))
        log.info("sweep order %d parts %d: %d iterations", order, p, its)
    return rows


def sweep_table(rows: list[Row]) -> str:
    """Markdown table of :func:`parts_sweep` rows (iterations, seconds, load average)."""
    lines = ["| order | dofs | parts | iterations | setup s | solve s | load avg |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {r.order} | {r.ndof:,} | {r.parts:,} | {r.iterations} | {r.setup_s:.2f} | {r.solve_s:.2f} | "
              f"{r.load:.1f} |" for r in rows]
    return "\n".join(lines) + "\n"


CUBE_SOLVERS = ("ddinverse-bddc", "ddinverse-fetidp", "ddinverse-bddc-edges", "ddinverse-fetidp-edges",
                "ngs-bddc-cg", "ngs-h1amg-cg", "sparsecholesky")


def cube_study(block: dict, cfg: dict) -> list[Row]:
    """The solvers of ``block["solvers"]`` (default :data:`CUBE_SOLVERS`) on the unit cube
    (:func:`make_cube_mesh`) for every (order, ndofs) of ``block["orders"]``, with ``cfg``'s
    ``dofs_per_part``, ``rtol`` and ``maxiter`` (same problem and timings as :func:`run_study`)."""
    sub = {"orders": block["orders"], "solvers": block.get("solvers", list(CUBE_SOLVERS)),
           "dofs_per_part": block.get("dofs_per_part", cfg.get("dofs_per_part", 4000)),
           "rtol": cfg.get("rtol", 1e-8), "maxiter": cfg.get("maxiter", 1000)}
    return run_study(sub, make_cube_mesh)


def cube_table(rows: list[Row]) -> str:
    """Markdown of :func:`cube_study` rows, with each case's DDInverse time over NGSolve's."""
    lines = rows_table(rows) + [""]
    by = {(r.solver, r.order, r.ndof): r for r in rows}
    for order, n in sorted({(r.order, r.ndof) for r in rows}):
        dd = [by[(s, order, n)] for s in CUBE_SOLVERS if s.startswith("ddinverse") and (s, order, n) in by
              and math.isfinite(by[(s, order, n)].total_s)]
        ngs_rows = [by[(s, order, n)] for s in ("ngs-bddc-cg", "ngs-h1amg-cg", "sparsecholesky")
                    if (s, order, n) in by and math.isfinite(by[(s, order, n)].total_s)]
        if dd and ngs_rows:
            best, ref = min(dd, key=lambda r: r.total_s), min(ngs_rows, key=lambda r: r.total_s)
            lines.append(f"- order {order}, {n} dofs: {best.solver} {best.total_s:.2f} s / {ref.solver} "
                         f"{ref.total_s:.2f} s = {best.total_s / ref.total_s:.2f} (fastest of each)")
    return "\n".join(lines) + "\n"


def hh_table(results: dict[int, dict], parts: int) -> str:
    """Markdown of :func:`hh_study` results per order: cond and iterations against H/h, and the fit
    cond = c0 + c1 (1 + log(H/h))^2 (H/h nominal, 4 * 2^r)."""
    lines = ["| order | H/h (nominal) | dofs | parts | iterations | cond | fit c0 + c1 (1 + log(H/h))^2 |",
             "|---|---|---|---|---|---|---|"]
    for order, out in results.items():
        fit = out["fit"]
        for i, (n, its, c, hr) in enumerate(zip(out["ndof"], out["iterations"], out["cond"], out["h_ratio"])):
            law = f"c0 = {fit['c0']:.3f}, c1 = {fit['c1']:.4f}" if i == 0 else ""
            lines.append(f"| {order} | {4 * hr} | {n:,} | {parts} | {its} | {c:.3f} | {law} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--parts-sweep"] and len(argv) == 4:
        # python -m ddstudies.ngsolve_bench --parts-sweep ORDER NDOF 64,256,1024   (markdown on stdout)
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        rows = parts_sweep(int(argv[1]), int(argv[2]), [int(p) for p in argv[3].split(",")])
        sys.stdout.write(sweep_table(rows))
        return 0
    if argv[:1] == ["--hh-study"] and len(argv) in (4, 6, 7):
        # python -m ddstudies.ngsolve_bench --hh-study 1,2,3,4 PARTS 0,1,2,3 [DIM MAXH [PRIMAL]]   (markdown)
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        refs = tuple(int(r) for r in argv[3].split(","))
        dim, maxh = (int(argv[4]), float(argv[5])) if len(argv) >= 6 else (2, 0.05)
        primal = argv[6] if len(argv) == 7 else "vertices"
        results = {int(o): hh_study(int(o), int(argv[2]), refs, maxh=maxh, dim=dim, primal=primal)
                   for o in argv[1].split(",")}
        sys.stdout.write(hh_table(results, int(argv[2])))
        return 0
    if argv[:1] == ["--scaling-study"] and len(argv) == 5:
        # python -m ddstudies.ngsolve_bench --scaling-study 1,2 0.06,0.03,0.015 12,30,100 stripes   (markdown)
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        rows = scaling_study([int(o) for o in argv[1].split(",")], [float(h) for h in argv[2].split(",")],
                             [int(p) for p in argv[3].split(",")], argv[4])
        sys.stdout.write(scaling_table(rows, argv[4]))
        return 0
    if argv[:1] == ["--cube-study"] and len(argv) in (3, 4):
        # python -m ddstudies.ngsolve_bench --cube-study 1,2,3 250000 [DOFS_PER_PART]   (markdown on stdout)
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        block = {"orders": [{"order": int(o), "ndofs": [int(n) for n in argv[2].split(",")]}
                            for o in argv[1].split(",")]}
        cfg = {"dofs_per_part": int(argv[3])} if len(argv) == 4 else {}
        sys.stdout.write(cube_table(cube_study(block, cfg)))
        return 0
    if len(argv) != 4:
        print("usage: python -m ddstudies.ngsolve_bench CONFIG.json OUT.csv OUT.md OUT.png", file=sys.stderr)
        return 2
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    cfg = json.loads(Path(argv[0]).read_text()) if argv[0].endswith(".json") else json.loads(argv[0])
    rows = run_study(cfg)
    tmp = argv[1] + ".tmp"
    with open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(asdict(rows[0])))
        writer.writeheader()
        writer.writerows(asdict(r) for r in rows)
    os.replace(tmp, argv[1])
    text = summary(rows)
    for block in cfg.get("scaling_study", []) or []:
        study = scaling_study(block["orders"], block["maxh"], block["parts"], block["pattern"])
        text += "\n## Scaling where METIS parts cut coefficient jumps (bddc)\n\n" + scaling_table(study, block["pattern"])
    if cfg.get("cube"):
        text += ("\n## 3D: the same problem on the unit cube (tetrahedra)\n\n"
                 + cube_table(cube_study(cfg["cube"], cfg)))
    _write_atomic(argv[2], text)
    plot(rows, argv[3])
    return 0


def hh_study(order: int = 1, parts: int = 16, refinements: tuple[int, ...] = (0, 1, 2), maxh: float = 0.05,
             method: str = "bddc", dim: int = 2, primal: str = "vertices") -> dict:
    """Condition numbers at a fixed METIS partition of the coarse mesh while h halves (H/h doubles).

    The partition is computed once on the coarse mesh; a refined element gets
    the part of the coarse element containing its centroid (a point search
    per element: a study, not a timed path). ``dim=3``: the unit cube, refined
    by ``mesh.Refine()``, whose elements inherit the part of their coarse
    ancestor (:func:`ddsolve.ngsolve.local.refinement_roots`). ``primal`` as for
    :class:`~ddsolve.ngsolve.DDInverse`. Fits
    cond = c0 + c1 (1 + log(H/h))^2, with H/h = 4 * 2^r as a nominal value,
    and returns the sizes, iterations, condition numbers and the fit.
    """
    import ngsolve as ngs
    from netgen.geom2d import unit_square

    from ddsolve.ngsolve import DDInverse
    from ddsolve.ngsolve.dofs import vertex_table
    from ddsolve.scene.partition import partition_elements

    if dim == 3:
        from netgen.csg import unit_cube

        from ddsolve.ngsolve.facets import facet_graph
        from ddsolve.ngsolve.local import refinement_roots

        geometry = unit_cube
    else:
        geometry = unit_square
    coarse = ngs.Mesh(geometry.GenerateMesh(maxh=maxh))
    V = vertex_table(coarse)
    label = partition_elements(V, parts, adjacency=facet_graph(V, 3) if dim == 3 else None)
    out = {"ndof": [], "iterations": [], "cond": [], "h_ratio": []}
    for r in refinements:
        if dim == 3:
            mesh = ngs.Mesh(geometry.GenerateMesh(maxh=maxh))
            for _ in range(r):
                mesh.Refine()
            coarse_el = refinement_roots(mesh)
        else:
            ngmesh = geometry.GenerateMesh(maxh=maxh)
            for _ in range(r):
                ngmesh.Refine()
            mesh = ngs.Mesh(ngmesh)
            centroids = _centroids(mesh)
            coarse_el = np.array([coarse(float(x), float(y)).nr for x, y in centroids])
        fes, a, f = _forms(mesh, order)
        inv = DDInverse(a, method=method, partition=label[coarse_el], rtol=1e-10, cond=True, primal=primal)
        gfu = ngs.GridFunction(fes)
        gfu.vec.data = inv * f.vec
        out["ndof"].append(fes.ndof)
        out["iterations"].append(inv.iterations)
        out["cond"].append(inv.cond)
        out["h_ratio"].append(2 ** r)
    logs = (1 + np.log(np.asarray(out["h_ratio"], dtype=float) * 4)) ** 2
    c1, c0 = np.polyfit(logs, np.asarray(out["cond"]), 1)
    out["fit"] = {"c0": float(c0), "c1": float(c1)}
    return out


def _centroids(mesh) -> np.ndarray:
    from ddsolve.ngsolve.dofs import vertex_table

    pts = np.asarray(mesh.ngmesh.Coordinates())[:, :2]
    return pts[vertex_table(mesh)].mean(axis=1)


def jump_form(mesh, order: int, pattern: str, jump: float = 1e4):
    """-div(c grad u) = 1, u = 0 on left and bottom, c in {1, jump}: ``"stripes"`` (six horizontal
    channels) or ``"checker"`` (a 5 x 5 checkerboard); (fes, a, f), a not assembled."""
    import ngsolve as ngs

    fes = ngs.H1(mesh, order=order, dirichlet="left|bottom")
    u, v = fes.TnT()
    if pattern == "stripes":
        coef = ngs.IfPos(ngs.sin(6 * math.pi * ngs.y + 1), jump, 1.0)
    elif pattern == "checker":
        coef = ngs.IfPos(ngs.sin(5 * math.pi * ngs.x) * ngs.sin(5 * math.pi * ngs.y), jump, 1.0)
    else:
        raise ValueError(f"pattern: expected 'stripes' or 'checker', got {pattern!r}")
    a = ngs.BilinearForm(fes)
    a += coef * ngs.grad(u) * ngs.grad(v) * ngs.dx
    f = ngs.LinearForm(fes)
    f += v * ngs.dx
    f.Assemble()
    return fes, a, f


def scaling_study(orders: list[int], maxhs: list[float], parts: list[int], pattern: str = "stripes",
                  scalings: tuple[str, ...] = ("diagonal", "deluxe")) -> list[dict]:
    """BDDC iterations, condition numbers and seconds (rtol 1e-10, ``cond=True``) of each scaling where
    METIS parts cut the coefficient jumps of :func:`jump_form` (unit square, netgen mesh of ``maxh``),
    and NGSolve's element BDDC + CG on the same form in the same process (its elements are its
    subdomains, so the jumps never cut them). Seconds are from the unassembled form to the solution."""
    import ngsolve as ngs
    from netgen.geom2d import unit_square
    from ngsolve.krylovspace import CGSolver

    from ddsolve.ngsolve import DDInverse

    rows = []
    for maxh in maxhs:
        mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=maxh))
        for order in orders:
            for p in parts:
                row = {"order": order, "maxh": maxh, "parts": p}
                for scaling in scalings:
                    fes, a, f = jump_form(mesh, order, pattern)
                    gfu = ngs.GridFunction(fes)
                    t = time.perf_counter()
                    inv = DDInverse(a, parts=p, rtol=1e-10, cond=True, scaling=scaling)
                    gfu.vec.data = inv * f.vec
                    row.update({"ndof": fes.ndof, "n_parts": inv.n_parts, f"{scaling}_its": inv.iterations,
                                f"{scaling}_cond": inv.cond, f"{scaling}_s": time.perf_counter() - t})
                fes, a, f = jump_form(mesh, order, pattern)
                gfu = ngs.GridFunction(fes)
                t = time.perf_counter()
                pre = ngs.Preconditioner(a, "bddc")
                a.Assemble()
                solver = CGSolver(a.mat, pre.mat, tol=1e-10, maxiter=5000)
                gfu.vec.data = solver * f.vec
                row.update({"ngs_bddc_its": solver.iterations, "ngs_bddc_s": time.perf_counter() - t})
                rows.append(row)
                log.info("scaling study: %s", row)
    return rows


def scaling_table(rows: list[dict], pattern: str) -> str:
    """Markdown table of :func:`scaling_study`."""
    lines = [f"Coefficient pattern: {pattern} (1 and 1e4), rtol 1e-10; seconds from the unassembled form.", "",
             ("| order | maxh | dofs | parts | iterations diagonal / deluxe | cond diagonal / deluxe "
              "| s diagonal / deluxe | NGSolve bddc+CG iterations, s |"),
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['order']} | {r['maxh']} | {r['ndof']:,} | {r['n_parts']} | {r['diagonal_its']} / "
                     f"{r['deluxe_its']} | {r['diagonal_cond']:.1f} / {r['deluxe_cond']:.1f} "
                     f"| {r['diagonal_s']:.2f} / {r['deluxe_s']:.2f} | {r['ngs_bddc_its']}, {r['ngs_bddc_s']:.2f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
