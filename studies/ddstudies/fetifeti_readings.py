"""Table 4.1: exact FETI-FETI condition numbers under several readings of the thesis.

For small cases of problem (4.32) the projected preconditioned dual operator
of FETI-FETI (Section 3.4, PCG on (3.35)) is formed densely and its exact
extreme eigenvalues are computed (no Lanczos estimate), under combinations of
the points the thesis leaves open:

* ``projection``: ``"weighted"`` (Q = diag(B_D^2 rho), ddsolve's default) or
  ``"orthogonal"`` (Q = I, the thesis's literal P = I - G (G^T G)^{-1} G^T);
* ``weights``: scaling of B_gl at body cross points: ``"all"`` (ddsolve: a
  copy's weight divided by the sum over all copies at its location, Dirichlet
  copies included), ``"free"`` (the sum over the free copies only) or
  ``"pair"`` (1/2 on both sides of every pair, whatever the multiplicity);
* ``redundancy``: ``"full"`` (every pair of copies at a location, ddsolve) or
  ``"tree"`` (a spanning tree of the active pairs at each location,
  non-redundant multipliers).

Dense matrices here are tiny analysis tools (dual dimension a few hundred).

    python -m ddstudies.fetifeti_readings --case 2,2,2 --case 4,2,2 \\
        --thesis config/thesis_tables/table_4_1.csv --out reports/table_4/table_4_1_readings.md
"""
from __future__ import annotations

import argparse
import csv
import itertools
import json
import os
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from .optimal import CONTACT_CASE, _atomic_write

__all__ = ["DualBlocks", "READINGS", "ReadingRow", "exact_condition", "main", "non_redundant", "render_markdown",
           "summary"]

PROJECTIONS = ("weighted", "orthogonal")
WEIGHTS = ("all", "free", "pair")
REDUNDANCY = ("full", "tree")
#: every combination, ddsolve's default first
READINGS = list(itertools.product(PROJECTIONS, WEIGHTS, REDUNDANCY))
#: the reading of ddsolve's ``preset="thesis"`` (FETI-FETI with the orthogonal projection)
THESIS_PRESET_READING = ("orthogonal", "all", "full")
DENSE_LIMIT = 1500


@dataclass(frozen=True)
class ReadingRow:
    """Exact spectrum of one case under one reading."""

    bodies: int
    subdomains: int
    elements: int
    contact: str
    projection: str
    weights: str
    redundancy: str
    n_dual: int
    lambda_min: float
    lambda_max: float
    cond: float
    thesis: float | None


def non_redundant(pairs_nodes: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Active mask keeping a spanning forest of the active pairs (union-find in pair order).

    Parameters
    ----------
    pairs_nodes : ndarray of int, shape (n_gl, 2)
        The two node copies of every pair.
    active : ndarray of bool, shape (n_gl,)

    Returns
    -------
    ndarray of bool, shape (n_gl,)
        Subset of ``active`` without the pairs that close a cycle.
    """
    parent: dict[int, int] = {}

    def find(x: int) -> int:
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    keep = np.zeros_like(active)
    for k in np.flatnonzero(active):
        a, b = find(int(pairs_nodes[k, 0])), find(int(pairs_nodes[k, 1]))
        if a != b:
            parent[a] = b
            keep[k] = True
    return keep


def _weights(gi: Any, sub: Any, kind: str) -> np.ndarray:
    if kind == "all":
        return gi.weight
    w = np.zeros(sub.n_W)
    if kind == "pair":
        w[gi.pairs.ravel()] = 0.5
        return w
    # "free": normalise over the free copies at a location (those appearing in pairs)
    rho = np.ones(sub.n_W) if sub.scaling == "multiplicity" else sub.rho[sub.sub_of_W] ** sub.gamma
    copies = np.unique(gi.pairs.ravel())
    coords = sub.scene.coords[sub.node_of_W[copies]]
    _, loc = np.unique(np.round(coords, 9), axis=0, return_inverse=True)
    total = np.bincount(loc.ravel(), weights=rho[copies])
    w[copies] = rho[copies] / total[loc.ravel()]
    return w


class DualBlocks:
    """Dense F = B A~^{-1} B^T and M^{-1} = B_D S~ B_D^T of one case and active set, per B_gl scaling.

    Rows are all active pairs (fully redundant); a non-redundant reading uses
    a subset of these rows, so its blocks are sub-matrices.
    """

    def __init__(self, solver: Any, active: np.ndarray) -> None:
        sub, gi = solver.sub, solver.gi
        self.solver, self.active = solver, active
        pairs = gi.pairs[active]
        n = pairs.shape[0]
        rows = np.r_[np.arange(n), np.arange(n)]
        self._rows, self._cols = rows, np.r_[pairs[:, 0], pairs[:, 1]]
        self._pairs = pairs
        B_gl = sp.csr_matrix((np.r_[np.ones(n), -np.ones(n)], (rows, self._cols)), shape=(n, sub.n_W))
        self.B = sp.vstack([solver.B_loc, B_gl]).tocsr()
        self.n_loc = solver.B_loc.shape[0]
        m = self.B.shape[0]
        if m > DENSE_LIMIT:
            raise ValueError(f"dense spectrum only for a dual space of size <= {DENSE_LIMIT}, got {m}")
        BT = self.B.T.toarray()
        F = self.B @ np.column_stack([solver.primal_solver.solve(BT[:, j]) for j in range(m)])
        self.F = 0.5 * (F + F.T)
        self._minv: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def preconditioner(self, weights: str) -> tuple[np.ndarray, np.ndarray]:
        """(M^{-1}, q) for a B_gl scaling; q = diag(B_D^2 rho), the weighted projection's Q."""
        if weights not in self._minv:
            sub, solver, pairs = self.solver.sub, self.solver, self._pairs
            w = _weights(solver.gi, sub, weights)
            n = pairs.shape[0]
            B_gl_D = sp.csr_matrix((np.r_[w[pairs[:, 1]], -w[pairs[:, 0]]], (self._rows, self._cols)),
                                   shape=(n, sub.n_W))
            B_D = sp.vstack([solver.B_loc_D, B_gl_D]).tocsr()
            BDT = B_D.T.toarray()
            Minv = B_D @ np.column_stack([solver._tilde_schur(BDT[:, j]) for j in range(BDT.shape[1])])
            q = np.asarray(B_D.multiply(B_D) @ sub.rho[sub.sub_of_W]).ravel()
            self._minv[weights] = (0.5 * (Minv + Minv.T), q)
        return self._minv[weights]


def exact_condition(blocks: DualBlocks, *, projection: str = "weighted", weights: str = "all",
                    redundancy: str = "full") -> tuple[int, float, float]:
    """Exact extreme eigenvalues of FETI-FETI's projected preconditioned operator.

    Parameters
    ----------
    blocks : DualBlocks
        The dense dual blocks of a case and active set.
    projection, weights, redundancy : str
        The reading (see the module docstring).

    Returns
    -------
    (n_dual, lambda_min, lambda_max)
        Dimension of the dual space (after the projection) and the extreme
        nonzero eigenvalues of ``P M^{-1} P^T F`` on range(P) (P the
        Q-orthogonal projection onto ker G^T).
    """
    solver = blocks.solver
    Minv, q = blocks.preconditioner(weights)
    F = blocks.F
    keep = np.ones(F.shape[0], dtype=bool)
    if redundancy == "tree":
        tree = non_redundant(solver.gi.pair_nodes, blocks.active)[blocks.active]
        keep[blocks.n_loc:] = tree
    F = F[np.ix_(keep, keep)]
    Minv = Minv[np.ix_(keep, keep)]
    if solver.floating.size:
        G = (blocks.B[keep] @ solver.R).toarray()
        sq = np.ones(F.shape[0]) if projection == "orthogonal" else np.sqrt(q[keep])
        F = sq[:, None] * F * sq[None, :]
        Minv = Minv / sq[:, None] / sq[None, :]
        U, s, _ = np.linalg.svd(sq[:, None] * G, full_matrices=True)
        rank = int(np.sum(s > 1e-12 * max(s.max(), 1e-300)))
        Z = U[:, rank:]                                 # orthonormal basis of ker((Q^{1/2} G)^T)
        F = Z.T @ F @ Z
        Minv = Z.T @ Minv @ Z
    # eigenvalues of Minv F (Minv SPD on the space): similar to Minv^{1/2} F Minv^{1/2}
    wM, VM = np.linalg.eigh(Minv)
    pos = wM > 1e-12 * wM.max()
    half = VM[:, pos] * np.sqrt(wM[pos])
    ev = np.linalg.eigvalsh(half.T @ F @ half)
    ev = ev[ev > 1e-10 * ev.max()]
    return int(F.shape[0]), float(ev.min()), float(ev.max())


def read_thesis_cond(path: str | os.PathLike | None) -> dict[tuple[int, int, int, str], float]:
    """Table 4.1's condition numbers keyed by ``(1/H_b, H_b/H_s, H_s/h, contact)``."""
    if not path or not Path(path).exists():
        return {}
    out = {}
    with open(path, newline="") as fh:
        for rec in csv.DictReader(fh):
            key = (int(rec["inv_Hb"]), int(rec["Hb_over_Hs"]), int(rec["Hs_over_h"]))
            for contact, case in CONTACT_CASE.items():
                if rec.get(f"cond_{case}") not in ("", None):
                    out[key + (contact,)] = float(rec[f"cond_{case}"])
    return out


def rows_for(cases: Sequence[Sequence[int]], contacts: Sequence[str], thesis: dict, *,
             f: str = "random:0", readings: Sequence[tuple[str, str, str]] = READINGS,
             max_n: int = 1100) -> list[ReadingRow]:
    """Exact condition numbers of every case, contact and reading (cases above ``max_n`` skipped,
    :func:`ddstudies.optimal.approximate_size`)."""
    from threadpoolctl import threadpool_limits

    from ddsolve.multibody import GlobalInterface
    from ddsolve.multibody.fetifeti import FetiFetiSolver
    from ddsolve.prepared import prepare
    from ddsolve.spec import ProblemSpec

    from .optimal import approximate_size

    rows = []
    for nb, ns, m in cases:
        if approximate_size(nb, ns, m) > max_n:
            continue
        spec = ProblemSpec.from_mapping(dict(problem="multibody", method="feti-feti", bodies=nb,
                                             subdomains=ns, elements=m, f=f))
        with threadpool_limits(1, "blas"):
            prep = prepare(spec)
            gi = GlobalInterface(prep.sub)
            solver = FetiFetiSolver(prep.sub, gi)
            for contact in contacts:
                blocks = DualBlocks(solver, gi.contact_mask(contact))
                for proj, wts, red in readings:
                    n, lo, hi = exact_condition(blocks, projection=proj, weights=wts, redundancy=red)
                    rows.append(ReadingRow(nb, ns, m, contact, proj, wts, red, n, lo, hi, hi / lo,
                                           thesis.get((nb, ns, m, contact))))
    return rows


def summary(rows: Sequence[ReadingRow]) -> str:
    """Computed statement: per case, ddsolve's reading and the reading closest to the thesis."""
    out = []
    keys = sorted({(r.bodies, r.subdomains, r.elements, r.contact) for r in rows})
    worst = 0.0
    for key in keys:
        rs = [r for r in rows if (r.bodies, r.subdomains, r.elements, r.contact) == key]
        th = rs[0].thesis
        if th is None:
            continue
        best = min(rs, key=lambda r: abs(r.cond - th))
        default = rs[0]
        literal = next((r for r in rs if (r.projection, r.weights, r.redundancy) == THESIS_PRESET_READING), None)
        dev = best.cond / th - 1
        worst = max(worst, abs(dev))
        out.append(f"({key[0]},{key[1]},{key[2]}) case {CONTACT_CASE[key[3]]}: thesis {th:.4f}, "
                   f"ddsolve's reading {default.cond:.4f} ({default.cond / th - 1:+.1%}), closest "
                   f"{best.cond:.4f} ({dev:+.1%}; projection {best.projection}, weights {best.weights}, "
                   f"multipliers {best.redundancy})"
                   + (f", thesis preset {literal.cond:.4f} ({literal.cond / th - 1:+.1%})" if literal else ""))
    if not out:
        return "No case has a thesis value."
    return ("Exact condition numbers against Table 4.1. " + "; ".join(out) +
            f". Largest remaining deviation of the closest reading: {worst:.1%}.")


def render_markdown(rows: Sequence[ReadingRow]) -> str:
    lines = ["# Table 4.1: exact FETI-FETI condition numbers under the readings of the thesis", "",
             "Readings: projection (weighted Q = diag(B_D^2 rho) or orthogonal Q = I), the scaling of "
             "B_gl at body cross points (all: normalised over all copies at a location, Dirichlet copies "
             "included; free: over the free copies; pair: 1/2 on each side) and the global multipliers "
             "(full: fully redundant; tree: non-redundant spanning tree). First row of each case: "
             "ddsolve's default reading. Exact eigenvalues of the projected preconditioned operator "
             "(dense; no Lanczos estimate).", "",
             "| 1/H_b | H_b/H_s | H_s/h | case | projection | weights | multipliers | n_dual | λ_min | λ_max "
             "| cond | thesis | cond/thesis − 1 |", "|" + "---|" * 13]
    for r in rows:
        dev = f"{r.cond / r.thesis - 1:+.1%}" if r.thesis else "–"
        lines.append(f"| {r.bodies} | {r.subdomains} | {r.elements} | {CONTACT_CASE[r.contact]} | "
                     f"{r.projection} | {r.weights} | {r.redundancy} | {r.n_dual} | {r.lambda_min:.4f} | "
                     f"{r.lambda_max:.4f} | {r.cond:.4f} | {r.thesis if r.thesis is not None else '–'} | {dev} |")
    lines += ["", summary(rows), ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ddstudies.fetifeti_readings", description=__doc__.splitlines()[0])
    p.add_argument("--case", action="append", required=True, help="1/H_b,H_b/H_s,H_s/h (repeatable)")
    p.add_argument("--contacts", nargs="+", default=["full", "middle"])
    p.add_argument("--thesis", default=None)
    p.add_argument("--f", default="random:0")
    p.add_argument("--max-n", type=int, default=1100)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    cases = [tuple(int(v) for v in c.split(",")) for c in args.case]
    rows = rows_for(cases, args.contacts, read_thesis_cond(args.thesis), f=args.f, max_n=args.max_n)
    out = Path(args.out)
    _atomic_write(out.with_suffix(".json"), json.dumps([asdict(r) for r in rows], indent=1))
    _atomic_write(out, render_markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
