"""Run under mpiexec by test_scattered_mpi.py: what one rank holds after its setup, as JSON on stdout.

Usage: rank_memory_case.py METHOD {structured,unstructured} CHECK(0/1)

Rank 0 prints one line per rank ``{"rank", "largest", "path", "n_W_rank", "local", "n_W", "ndof", "topo", "scene"}``:
``largest`` is the first dimension of the largest numpy array reachable from its
:class:`~ddsolve.parallel.setup.RankProblem` (sparse matrices and NGSolve objects not counted: their
size is that of the rank's own matrices); ``local`` the largest of the rank's own counts (its W entries,
nodes and elements); ``n_W`` the global W.
"""
import dataclasses
import json
import sys

import numpy as np
from mpi4py import MPI

from ddsolve.parallel.comm import CountingComm
from ddsolve.parallel.setup import prepare_rank
from ddsolve.spec import ProblemSpec


def largest_array(obj, seen=None) -> tuple[int, str]:
    """(first dimension, path) of the largest ndarray reachable through dataclasses, dicts, sequences and
    plain objects' attributes."""
    seen = set() if seen is None else seen
    best = (0, "")
    stack = [(obj, "prob")]
    while stack:
        x, path = stack.pop()
        if id(x) in seen:
            continue
        seen.add(id(x))
        if isinstance(x, np.ndarray):
            if x.ndim and x.shape[0] > best[0]:
                best = (int(x.shape[0]), path)
            continue
        if isinstance(x, dict):
            stack += [(v, f"{path}[{k!r}]") for k, v in x.items()]
        elif isinstance(x, (list, tuple)):
            stack += [(v, f"{path}[{i}]") for i, v in enumerate(x)]
        elif dataclasses.is_dataclass(x) or (hasattr(x, "__dict__") and type(x).__module__.startswith("ddsolve")):
            stack += [(v, f"{path}.{k}") for k, v in vars(x).items() if k not in ("spec", "comm")]
    return best


if __name__ == "__main__":
    method, kind, check = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
    if method in ("feti-feti", "hybrid"):
        spec = dict(problem="multibody", method=method, bodies=2, subdomains=3, elements=6, check=check)
    elif method == "active-set":
        spec = dict(problem="contact", method=method, subdomains=3, elements=6, check=check)
    elif kind == "structured":
        spec = dict(method=method, subdomains=6, elements=6, check=check)
    else:
        spec = dict(method=method, mesh="unstructured", maxh=0.04, parts=12, check=check)
    comm = CountingComm(MPI.COMM_WORLD)
    prob = prepare_rank(ProblemSpec.from_mapping(spec), comm)
    size, path = largest_array(prob)
    local = prob.sub.scene
    row = {"rank": comm.rank, "largest": size, "path": path, "n_W_rank": int(prob.sub.n_W),
                      "local": max(int(prob.sub.n_W), local.n_nodes, local.elements.shape[0]),
                      "n_W": comm.comm.allreduce(int(prob.sub.n_W)), "ndof": prob.ndof,
                      "topo": prob.topo is not None, "scene": prob.scene is not None}
    rows = comm.comm.gather(row, root=0)
    if comm.rank == 0:
        print("\n".join(json.dumps(r) for r in rows), flush=True)
