"""KKT residuals (5.5) and energy of the distributed active set method, computed without assembling (issue 14).

Each test launches ``mpiexec -n P`` (marker ``mpi``) on ``kkt_case.py``: the distributed solve, its
:meth:`~ddsolve.parallel.active_set.DistributedActiveSetHybrid.measures`, rank 0's serial
:meth:`~ddsolve.contact.problem.ContactProblem.kkt` of the same (u, lambda) (test only), and the
:func:`ddsolve.parallel.solve` of the command line with ``ddsolve.prepared.prepare`` counted on every rank.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from ddsolve.api import SOLVERS
from ddsolve.contact.run import contact_result_fields
from ddsolve.prepared import prepare
from ddsolve.spec import ProblemSpec

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch import HERE, MPI_MARKS, mpiexec  # noqa: E402
from mpi_case import case  # noqa: E402

pytestmark = MPI_MARKS
KEYS = ("kkt_feasibility", "kkt_dual_feasibility", "kkt_complementarity", "kkt_stationarity", "kkt_residual")


def _run(tmp_path: Path, kind: str, n: int, check: bool) -> dict:
    out = tmp_path / "kkt.npz"
    proc = mpiexec(n, [str(HERE / "kkt_case.py"), kind, "1" if check else "0", str(out)])
    assert proc.returncode == 0, proc.stderr
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


def _close(a: float, b: float) -> bool:
    """1e-10 relative, or 1e-14 absolute (values near 0; the stationarity's rounding floor, see below)."""
    return abs(a - b) <= max(1e-10 * abs(b), 1e-14)


@pytest.mark.parametrize("kind", ["structured", "unstructured"])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_distributed_kkt_equals_serial(tmp_path, kind, n):
    par = _run(tmp_path, kind, n, check=False)
    assert int(par["n_ranks"]) == n and bool(par["converged"]) and bool(par["result_converged"])
    dist, ser = par["dist"], par["serial"]
    # the gap B u, ||u||_inf, ||lambda||: from the values of the gathered u, bitwise
    assert dist[:3].tolist() == ser[:3].tolist()
    assert ser[0] > 0.0 and ser[2] > 0.0           # not trivially equal: a penetration and lambda^T B u remain
    # stationarity ||K u - f + B^T lambda|| / scale: sum_i R_i^T K_i u_i instead of the assembled K u; the
    # residual is ~4e-6 of the forces it balances, so rounding moves it by ~1e-15 absolute (measured
    # <= 9e-16; worst-case bound 2 m eps || |K| |u| || / scale ~ 8e-13): equal to 1e-14 absolute
    assert all(_close(float(d), float(s)) for d, s in zip(dist[3:5], ser[3:5])), (dist, ser)
    assert abs(dist[5] - ser[5]) <= 1e-10 * abs(ser[5])       # energy (measured <= 2e-14)
    # the penetration weighted by the stiffness: diag K summed from the subdomains instead of assembled
    weighted = par["weighted"]
    assert weighted[1] > 0.0 and abs(weighted[0] - weighted[1]) <= 1e-12 * weighted[1], weighted
    assert weighted[2] == weighted[0]                           # the result reports it
    assert par["n_contact"][0] == par["n_contact"][1] > 0
    # the result of ddsolve.parallel.solve reports these very values, and no rank called prepare()
    assert par["result"].tolist() == dist.tolist()
    assert par["prepare_calls"].tolist() == [0] * n
    # without --check the command line gathers no global u on rank 0; the same numbers
    assert bool(par["bare_u_is_none"]) and par["bare_result"].tolist() == par["result"].tolist()
    assert par["bare_iterations"][0] == par["bare_iterations"][1]

    # against the serial run: its u differs by the other summation order (to ~1e-10, test_mpi.py);
    # the KKT residual is what the face solves (rtol 1e-5) left over and follows u's rounding
    spec, scene = case("active-set", kind)
    prep = prepare(spec, scene)
    serial = contact_result_fields(ProblemSpec.from_mapping(spec), prep.contact,
                                   SOLVERS["contact"]["active-set"](prep))["extra"]
    assert abs(par["result"][4] - serial["kkt_residual"]) <= 1e-8 * serial["kkt_residual"]
    assert abs(par["result"][5] - serial["energy"]) <= 1e-12 * abs(serial["energy"])
    assert par["result"][1] == serial["kkt_dual_feasibility"] == 0.0


def test_check_assembles_once_on_rank_0(tmp_path):
    """With ``check`` the direct reference is assembled serially, on rank 0 only (the instrument counts)."""
    par = _run(tmp_path, "unstructured", 2, check=True)
    assert par["prepare_calls"].tolist() == [1, 0]
    assert not bool(par["bare_u_is_none"])          # --check needs u on rank 0
    assert par["result"].tolist() == par["dist"].tolist()
