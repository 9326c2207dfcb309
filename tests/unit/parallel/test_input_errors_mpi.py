"""Input errors found only while a rank builds its problem (a mesh file) exit 2 on every rank, one line each.

Found by a black-box review of ``mpiexec -n P ddsolve solve``: these ended in ``MPI_Abort`` (exit 1,
``rank r: InputError: ...``), a ``ValueError`` of the ranks that owned no subdomain, or a
traceback (an mpi4py whose import fails with another exception than ImportError: tested in
test_mpi.py::test_without_mpi4py_is_a_clear_error).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch import MPI_MARKS, ROOT, TIMEOUT, mpi_env, mpiexec  # noqa: E402

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


def _run_with_files(tmp_path, paths: str, problem: str, method: str):
    """``main`` on 2 ranks, rank r reading the mesh file ``[paths][r]`` (as if ranks saw different files)."""
    code = ("import sys; from mpi4py import MPI; from ddsolve.spec import ProblemSpec; "
            "from ddsolve.parallel.run import main; "
            f"path = {paths}[MPI.COMM_WORLD.Get_rank()]; "
            f"spec = ProblemSpec.from_mapping(dict(mesh='unstructured', mesh_file=path, parts=2, "
            f"problem={problem!r}, method={method!r})); "
            "sys.exit(main(spec, True, str))")
    return mpiexec(2, ["-c", code])


@pytest.mark.parametrize("problem,method", [("poisson", "fetidp"), ("multibody", "hybrid")])
def test_input_error_of_rank_0_is_raised_on_every_rank(tmp_path, problem, method):
    """Rank 0 alone reads the mesh file: its error reaches every rank; no hang, exit 2."""
    mesh = _square_mesh(tmp_path / "square.vol")
    bad = tmp_path / "bad.vol"
    bad.write_text("not a mesh\n")
    proc = _run_with_files(tmp_path, repr([str(bad), str(mesh)]), problem, method)
    _one_error_per_rank(proc, 2, f"mesh_file: {bad} is not a netgen mesh")


def test_other_ranks_never_read_the_mesh_file(tmp_path):
    """A file only rank 1 would find corrupt is never read by rank 1: the solve runs on rank 0's mesh."""
    mesh = _square_mesh(tmp_path / "square.vol")
    bad = tmp_path / "bad.vol"
    bad.write_text("not a mesh\n")
    proc = _run_with_files(tmp_path, repr([str(mesh), str(bad)]), "poisson", "fetidp")
    assert proc.returncode == 0, proc.stderr
    assert '"n_ranks": 2' in proc.stdout and '"converged": true' in proc.stdout


@pytest.mark.parametrize("method,problem", [("smalbe", "contact"), ("direct", "multibody")])
def test_refused_method_message_is_whole(method, problem):
    """The refusal names every distributed method in full (was clipped in the middle to 150 characters)."""
    proc = mpiexec(2, ["-m", "ddsolve", "solve", "--problem", problem, "--method", method,
                       "--subdomains", "2", "--elements", "2"])
    _one_error_per_rank(proc, 2, f"method: {problem}/{method} is not distributed (mpiexec: poisson: fetidp, "
                                 f"bddc, feti; multibody: feti-feti, hybrid; contact: active-set); "
                                 f"run it without mpiexec\n")


def test_error_line_is_one_write(monkeypatch):
    """The command line writes its error line in one call (``print`` made two: the line, then the newline,
    and under mpiexec the launcher joined the lines of two ranks: ``...'direct'ddsolve: error: ...``)."""
    import io

    from ddsolve.cli import main

    calls: list[str] = []

    class Recorder(io.StringIO):
        def write(self, text: str) -> int:
            calls.append(text)
            return len(text)

    monkeypatch.setattr(sys, "stderr", Recorder())
    assert main(["solve", "--subdomains", "0"]) == 2
    assert calls == ["ddsolve: error: subdomains: must be an integer in [1, 2147483647], got '0'\n"]


def _per_rank_command(tmp_path, per_rank_args: str) -> subprocess.CompletedProcess:
    """``ddsolve.cli.main`` on 2 ranks, rank r with the command line ``[per_rank_args][r]``."""
    code = ("import sys, os; from ddsolve.cli import main; "
            f"sys.exit(main({per_rank_args}[int(os.environ['PMI_RANK'])]))")
    return mpiexec(2, ["-c", code])


def test_an_input_error_of_one_rank_before_mpi_is_agreed_on(tmp_path):
    """A mesh file (or scene file) that only rank 0 can see, as on node-local disks: rank 1 refused the input
    before any MPI call and exited 2 while rank 0 waited in MPI forever (fifth review). The ranks now agree
    on their input checks first (one allgather): every rank prints rank 1's line and exits 2."""
    mesh = _square_mesh(tmp_path / "square.vol")
    missing = tmp_path / "only_on_rank_0.vol"
    args = repr([["solve", "--mesh", "unstructured", "--mesh-file", str(mesh), "--parts", "2"],
                 ["solve", "--mesh", "unstructured", "--mesh-file", str(missing), "--parts", "2"]])
    proc = _per_rank_command(tmp_path, args)
    _one_error_per_rank(proc, 2, "mesh_file: no such file: '")       # the path is clipped in the middle
    assert proc.stderr.count("only_on_rank_0.vol'") == 2
    scene = tmp_path / "scene.yaml"
    scene.write_text("subdomains: 2\nelements: 4\n")
    args = repr([["solve", str(scene)], ["solve", str(tmp_path / "missing.yaml")]])
    proc = _per_rank_command(tmp_path, args)
    assert proc.returncode == 2 and proc.stderr.count("ddsolve: error: ") == 2, proc.stderr
    assert "missing.yaml" in proc.stderr and "Traceback" not in proc.stderr


def test_a_launcher_that_is_not_mpi4pys_is_refused():
    """Started with another MPI's environment (here Open MPI's variables on a plain process), mpi4py's MPICH
    made each process a job of its own: P full solves, P JSON lines, exit 0 (fifth review)."""
    env = {k: v for k, v in mpi_env().items() if not k.startswith(("PMI_", "HYDRA", "MPIR", "PMIX"))}
    env.update(OMPI_COMM_WORLD_SIZE="2", OMPI_COMM_WORLD_RANK="0")
    proc = subprocess.run([sys.executable, "-m", "ddsolve", "solve", "--subdomains", "2", "--elements", "2", "--json"],
                          capture_output=True, text=True, timeout=TIMEOUT, env=env, cwd=ROOT)
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    assert "ddsolve: error: mpi: the launcher started 2 processes but MPI sees 1" in proc.stderr


def test_one_rank_without_mpi4py_runs_the_serial_solver(tmp_path):
    """``mpiexec -n 1`` without a working mpi4py was an error ("with 1 ranks needs mpi4py"); one rank is the
    serial solve, with the same answer."""
    broken = tmp_path / "mpi4py"
    broken.mkdir()
    (broken / "__init__.py").write_text('raise ImportError("mpi4py broken (test)")\n')
    proc = mpiexec(1, ["-m", "ddsolve", "solve", "--subdomains", "3", "--elements", "4", "--json"],
                   PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT), str(ROOT / "studies")]))
    assert proc.returncode == 0, proc.stderr
    assert '"converged": true' in proc.stdout and '"n_ranks"' not in proc.stdout


def test_a_coefficient_that_overflows_the_matrices_exits_2():
    """rho = 1e308 times the Q1 entries is inf: a breakdown at iteration 0 after an overflow warning, before."""
    proc = mpiexec(2, ["-m", "ddsolve", "solve", "--rho", "checkerboard:1e308", "--subdomains", "2",
                       "--elements", "2"])
    _one_error_per_rank(proc, 2, "rho: the largest rho, 1e+308, times the element matrices overflows")


def _same_line_on_both_ranks(proc, line: str) -> None:
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("ddsolve: error: ") == 2 and proc.stderr.count(f"ddsolve: error: {line}") == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "Abort" not in proc.stderr and proc.stdout == "", proc.stderr


def _mpmd(first: list[str], second: list[str], cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """``mpiexec -n 1 python FIRST : -n 1 python SECOND``: two ranks given different arguments."""
    from launch import MPIEXEC

    return subprocess.run([MPIEXEC, "-n", "1", sys.executable, *first, ":", "-n", "1", sys.executable, *second],
                          capture_output=True, text=True, timeout=TIMEOUT, env=mpi_env(), cwd=cwd)


@pytest.mark.parametrize("first, second, line", [
    (["--rtol", "1e-3"], ["--rtol", "1e-10"], "input: rank 1 was given other input than rank 0 (rtol: 1e-10, rank 0: 0.001)"),
    (["--subdomains", "4"], ["--subdomains", "6", "--method", "bddc"], "input: rank 1 was given other input than rank 0 (method: 'bddc'"),
    (["--subdomains", "4"], ["--subdomains", "6"], "input: rank 1 was given other input than rank 0 (subdomains: 6"),
    (["--output", "a.vtu"], [], "input: rank 1 was given other input than rank 0 (output: None, rank 0: '<given>')"),
])
def test_ranks_given_different_input_exit_2_instead_of_hanging(tmp_path, first, second, line):
    """A review: different rtol or method hung until killed; different subdomains solved rank 0's scene."""
    solve = ["-m", "ddsolve", "solve", "--json"]
    proc = _mpmd(solve + first, solve + second, cwd=tmp_path)
    _same_line_on_both_ranks(proc, line)
    assert list(tmp_path.iterdir()) == []


def test_scene_files_of_one_name_must_agree_but_not_their_paths(tmp_path):
    """Node-local disks: each rank reads s.yaml in its own directory. Other contents exit 2 on every rank;
    the same contents solve, though the output path (relative to each scene file) differs."""
    for rank, rtol in ((0, "1e-6"), (1, "1e-8")):
        (tmp_path / f"n{rank}").mkdir()
        (tmp_path / f"n{rank}" / "s.yaml").write_text(f"subdomains: 3\nelements: 4\nrtol: {rtol}\noutput: u.vtu\n")
    scene = ["-m", "ddsolve", "solve", "--json"]
    proc = _mpmd(scene + [str(tmp_path / "n0" / "s.yaml")], scene + [str(tmp_path / "n1" / "s.yaml")])
    _same_line_on_both_ranks(proc, "input: rank 1 was given other input than rank 0 (rtol: 1e-08, rank 0: 1e-06)")
    (tmp_path / "n1" / "s.yaml").write_text((tmp_path / "n0" / "s.yaml").read_text())
    proc = _mpmd(scene + [str(tmp_path / "n0" / "s.yaml")], scene + [str(tmp_path / "n1" / "s.yaml")])
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "n0" / "u.vtu").is_file() and not (tmp_path / "n1" / "u.vtu").exists()


def test_srun_tasks_without_pmi_are_refused():
    """srun -n 2 with SLURM's MpiDefault=none sets SLURM_STEP_NUM_TASKS but no PMI variable: each process was an
    MPI singleton solving the whole problem, two JSON lines, exit 0 (a review)."""
    env = {k: v for k, v in mpi_env().items() if not k.startswith(("PMI_", "HYDRA", "MPIR", "PMIX", "OMPI_"))}
    env.update(SLURM_STEP_NUM_TASKS="2", SLURM_PROCID="0")
    proc = subprocess.run([sys.executable, "-m", "ddsolve", "solve", "--subdomains", "2", "--elements", "2", "--json"],
                          capture_output=True, text=True, timeout=TIMEOUT, env=env, cwd=ROOT)
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    assert "srun started 2 tasks but MPI sees 1" in proc.stderr and "--mpi=pmi2" in proc.stderr
