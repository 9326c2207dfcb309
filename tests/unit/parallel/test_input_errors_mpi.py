"""Input errors found only while a rank builds its problem (a mesh file) exit 2 on every rank, one line each.

Found by a black-box review of ``mpiexec -n P ddsolve solve``: these ended in ``MPI_Abort`` (exit 1,
``rank r: InputError: ...``) or a ``ValueError`` of the ranks that owned no subdomain.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch import MPI_MARKS, mpiexec  # noqa: E402

pytestmark = MPI_MARKS


def _square_mesh(path: Path) -> Path:
    """A netgen mesh of the unit square (maxh 0.2, one material): 4 METIS parts at most make sense."""
    from netgen.geom2d import unit_square

    unit_square.GenerateMesh(maxh=0.2).Save(str(path))
    return path


def _one_error_per_rank(proc, n: int, line: str) -> None:
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("ddsolve: error: ") == n, proc.stderr
    assert proc.stderr.count(f"ddsolve: error: {line}") == n, proc.stderr
    assert "Traceback" not in proc.stderr and "rank " not in proc.stderr and "Abort" not in proc.stderr, proc.stderr
    assert proc.stdout == ""


def test_mesh_file_with_fewer_parts_than_ranks_exits_2(tmp_path):
    mesh = _square_mesh(tmp_path / "square.vol")
    proc = mpiexec(3, ["-m", "ddsolve", "solve", "--mesh", "unstructured", "--mesh-file", str(mesh),
                       "--parts", "2"])
    _one_error_per_rank(proc, 3, "parts: 2 subdomains for 3 ranks")


def test_mesh_file_that_is_not_a_mesh_exits_2(tmp_path):
    bad = tmp_path / "bad.vol"
    bad.write_text("not a mesh\n")
    proc = mpiexec(2, ["-m", "ddsolve", "solve", "--mesh", "unstructured", "--mesh-file", str(bad)])
    _one_error_per_rank(proc, 2, "mesh_file: ")


def test_input_error_of_one_rank_only_is_raised_on_every_rank(tmp_path):
    """A mesh file that only rank 1 finds corrupt (as if ranks saw different files): no hang, exit 2."""
    mesh = _square_mesh(tmp_path / "square.vol")
    bad = tmp_path / "bad.vol"
    bad.write_text("not a mesh\n")
    code = ("import sys; from mpi4py import MPI; from ddsolve.spec import ProblemSpec; "
            "from ddsolve.parallel.run import main; "
            f"path = [{str(mesh)!r}, {str(bad)!r}][MPI.COMM_WORLD.Get_rank() == 1]; "
            "spec = ProblemSpec.from_mapping(dict(mesh='unstructured', mesh_file=path, parts=2)); "
            "sys.exit(main(spec, True, str))")
    proc = mpiexec(2, ["-c", code])
    _one_error_per_rank(proc, 2, f"mesh_file: {bad} is not a netgen mesh")
