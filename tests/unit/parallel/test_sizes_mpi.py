"""Subdomain counts under mpiexec: every body counted, the JSON sizes of the serial run, a load that cannot travel.

Found by a black-box review of the distributed solves: ``check_supported`` counted the METIS parts
of one body only (and one membrane of the contact problem), so it refused runs with enough
subdomains; a mesh file with several materials reported all subdomains in ``subdomains`` where
the serial run reports the parts per body; and a callable load on a scene given on rank 0 only
failed with a pickling traceback.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ddsolve.errors import InputError
from ddsolve.parallel.run import check_supported
from ddsolve.spec import ProblemSpec

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch import MPI_MARKS, ROOT, TIMEOUT, mpi_env, mpiexec  # noqa: E402


def _parallel_and_serial(n: int, args: list[str]) -> tuple[dict, dict]:
    """The JSON of ``mpiexec -n n python ARGS`` and of the serial ``python ARGS``."""
    proc = mpiexec(n, args)
    assert proc.returncode == 0, proc.stderr
    serial = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=TIMEOUT,
                            env=mpi_env(), cwd=ROOT, check=True)
    return json.loads(proc.stdout), json.loads(serial.stdout)


@pytest.mark.parametrize("spec,n_sub", [
    (dict(problem="multibody", method="feti-feti", mesh="unstructured", bodies=2, parts=3), 12),
    (dict(problem="contact", method="active-set", mesh="unstructured", parts=3), 6),
    (dict(problem="contact", method="active-set", subdomains=2, elements=4), 8),
    (dict(problem="multibody", method="hybrid", bodies=3, subdomains=2, elements=4), 36),
    (dict(method="fetidp", mesh="unstructured", parts=5), 5),
])
def test_check_supported_counts_the_subdomains_of_every_body(spec, n_sub):
    spec = ProblemSpec.from_mapping(spec)
    check_supported(spec, n_sub)                              # one subdomain per rank: accepted
    with pytest.raises(InputError, match=f"{n_sub} subdomains for {n_sub + 1} ranks"):
        check_supported(spec, n_sub + 1)


@pytest.mark.mpi
@MPI_MARKS[1]
def test_contact_with_fewer_parts_than_ranks_runs_as_serial():
    """--parts 3 of each membrane gives 6 subdomains: 4 ranks are enough (it was refused)."""
    args = ["-m", "ddsolve", "solve", "--problem", "contact", "--mesh", "unstructured", "--parts", "3",
            "--maxh", "0.1", "--json"]
    par, ser = _parallel_and_serial(4, args)
    assert par["n_ranks"] == 4 and par["converged"] and ser["converged"]
    assert par["subdomains"] == ser["subdomains"] == 3 and par["ndof"] == ser["ndof"]
    assert par["iterations"] == ser["iterations"] > 0


@pytest.mark.mpi
@MPI_MARKS[1]
def test_mesh_file_of_two_bodies_reports_the_serial_sizes(tmp_path):
    from ddsolve.scene.unstructured import mesh_geometry

    mesh = tmp_path / "membranes.vol"
    mesh_geometry("contact", maxh=0.15).Save(str(mesh))
    args = ["-m", "ddsolve", "solve", "--problem", "contact", "--mesh", "unstructured", "--mesh-file", str(mesh),
            "--parts", "3", "--json"]
    par, ser = _parallel_and_serial(2, args)
    assert par["subdomains"] == ser["subdomains"] == 3 and par["elements"] == ser["elements"]
    assert par["ndof"] == ser["ndof"] and par["iterations"] == ser["iterations"]


@pytest.mark.mpi
@MPI_MARKS[1]
def test_callable_load_on_rank_0_only_is_an_input_error_on_every_rank():
    code = ("from mpi4py import MPI; from ddsolve.parallel import solve; from ddsolve.errors import InputError; "
            "from ddsolve.scene import structured_square; rank = MPI.COMM_WORLD.Get_rank(); "
            "scene = structured_square(1, 2, 4, rho=1.0); scene.f = lambda x, y: 1.0 + x; "
            "msg = None"
            "\ntry:\n    solve(dict(method='fetidp'), scene=scene if rank == 0 else None)"
            "\nexcept InputError as exc:\n    msg = str(exc)"
            "\nmsgs = MPI.COMM_WORLD.gather(msg)\nrank == 0 and print(json.dumps(msgs))")
    proc = mpiexec(2, ["-c", "import json; " + code])
    assert proc.returncode == 0, proc.stderr
    msgs = json.loads(proc.stdout)
    assert len(msgs) == 2 and all(m.startswith("scene: a callable load f cannot be sent") for m in msgs), msgs
