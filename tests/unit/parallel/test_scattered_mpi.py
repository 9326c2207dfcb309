"""The distributed setup: no rank but rank 0 ever holds an array of the global size.

Rank 0 builds the scene and the global topology, cuts one piece per rank and scatters them
(:mod:`ddsolve.parallel.setup`). Checked by walking every array a rank holds after its setup
(``rank_memory_case.py``); rank 0 under ``--check``, which keeps the global scene and topology,
is the contrast that shows the walk sees them where they are held.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from ddsolve.parallel.comm import SharedIndex, shared_indices

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch import HERE, MPI_MARKS, mpiexec  # noqa: E402


def _ranks(method: str, kind: str, n: int, check: bool) -> list[dict]:
    proc = mpiexec(n, [str(HERE / "rank_memory_case.py"), method, kind, "1" if check else "0"])
    assert proc.returncode == 0, proc.stderr
    rows = sorted((json.loads(line) for line in proc.stdout.splitlines()), key=lambda r: r["rank"])
    assert [r["rank"] for r in rows] == list(range(n))
    return rows


@pytest.mark.mpi
@MPI_MARKS[1]
@pytest.mark.parametrize("method,kind", [("fetidp", "structured"), ("bddc", "unstructured"),
                                         ("fetidp", "unstructured"), ("feti", "structured"),
                                         ("feti-feti", "structured"), ("hybrid", "structured"),
                                         ("active-set", "structured")])
def test_scattered_ranks_hold_only_their_share(method, kind):
    rows = _ranks(method, kind, 3, check=False)
    for r in rows:
        assert not r["topo"] and not r["scene"], r                # rank 0 dropped them too
        assert r["largest"] <= r["local"], r                      # nothing beyond the rank's own share
        assert r["n_W_rank"] <= 0.45 * r["n_W"], r                # and that share is about a third


@pytest.mark.mpi
@MPI_MARKS[1]
def test_check_keeps_the_global_scene_on_rank_0_only():
    rows = _ranks("bddc", "unstructured", 2, check=True)
    assert rows[0]["topo"] and rows[0]["scene"] and rows[0]["largest"] >= rows[0]["n_W"] > rows[0]["local"]
    assert not rows[1]["topo"] and not rows[1]["scene"] and rows[1]["largest"] <= rows[1]["local"]


@pytest.mark.mpi
@MPI_MARKS[1]
def test_scene_on_rank_0_only_equals_scene_on_every_rank():
    """``solve(spec, scene)`` with the scene on rank 0 only (the others get their parts sent) gives the
    same answer as with the scene on every rank (each cuts its own part)."""
    code = ("import sys, json, numpy as np; from mpi4py import MPI; from ddsolve.parallel import solve; "
            "from ddsolve.scene import unstructured_scene; rank = MPI.COMM_WORLD.Get_rank(); "
            "scene = unstructured_scene('poisson', maxh=0.08, parts=5, rho=np.geomspace(1.0, 1e2, 5), seed=0); "
            "out = [solve(dict(method='bddc', rtol=1e-10), scene=s) for s in (scene, scene if rank == 0 else None)]; "
            "rank == 0 and print(json.dumps([[r.iterations, np.asarray(r.u).tolist()] for r in out]))")
    proc = mpiexec(3, ["-c", code])
    assert proc.returncode == 0, proc.stderr
    (it_all, u_all), (it_root, u_root) = json.loads(proc.stdout)
    assert it_all == it_root > 0
    assert np.array_equal(np.asarray(u_all), np.asarray(u_root))


def _brute_force(gid, rank, size, n_global):
    out = []
    for q in range(size):
        local = np.unique(gid[rank == q])
        lowest = {g: rank[gid == g].min() for g in local}
        neighbours = {}
        for p in range(size):
            if p != q:
                common = np.intersect1d(local, gid[rank == p])
                if common.size:
                    neighbours[p] = np.searchsorted(local, common)
        out.append((local, np.array([lowest[g] == q for g in local], dtype=bool), neighbours))
    return out


@pytest.mark.parametrize("seed", range(5))
def test_shared_indices_equal_brute_force(seed):
    rng = np.random.default_rng(seed)
    size, n_global, m = int(rng.integers(1, 6)), int(rng.integers(1, 40)), int(rng.integers(1, 120))
    gid, rank = rng.integers(0, n_global, m), rng.integers(0, size, m)
    got = shared_indices(gid, rank, size, n_global)
    expected = _brute_force(gid, rank, size, n_global)
    for q, ((local, owned, neighbours), (g_local, index)) in enumerate(zip(expected, got)):
        assert np.array_equal(g_local, local)
        assert np.array_equal(index.owned, owned) and index.n == local.size
        assert index.neighbours.keys() == neighbours.keys()
        for p in neighbours:
            assert np.array_equal(index.neighbours[p], neighbours[p])
        if local.size:
            one = SharedIndex.build(q, local, gid, rank, n_global)
            assert np.array_equal(one.owned, owned) and one.neighbours.keys() == neighbours.keys()
