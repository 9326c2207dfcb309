"""Distributed FETI-DP / BDDC / FETI under mpiexec agree with the serial solvers; errors end every rank.

Each test launches ``mpiexec -n P`` through subprocess (marker ``mpi``); skipped only when
``mpiexec`` or mpi4py is missing.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ddsolve.api import SOLVERS
from ddsolve.parallel.model import messages_bytes
from ddsolve.prepared import prepare

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch import HERE, ROOT, TIMEOUT, MPI_MARKS, mpi_env, mpiexec  # noqa: E402
from mpi_case import case  # noqa: E402

pytestmark = MPI_MARKS


def _serial(method: str, kind: str):
    spec, scene = case(method, kind)
    out = SOLVERS[spec.get("problem", "poisson")][method](prepare(spec, scene)).output
    return out


def _serial_ulp_sensitivity(method: str, kind: str) -> float:
    """||u(f (1 + 2^-52)) / (1 + 2^-52) - u(f)|| / ||u(f)|| of the serial solver: its own rounding sensitivity."""
    spec, scene = case(method, kind)
    prep = prepare(spec, scene)
    u = SOLVERS[spec["problem"]][method](prep).output.u
    s = 1.0 + 2.0 ** -52
    prep.sub.f_W = prep.sub.f_W * s
    u_s = SOLVERS[spec["problem"]][method](prep).output.u / s
    return float(np.linalg.norm(u_s - u) / np.linalg.norm(u))


def test_hybrid_middle_contact_is_rounding_sensitive_in_serial():
    """Why the distributed hybrid on contact (II) is compared at the serial solver's own sensitivity."""
    sensitivity = _serial_ulp_sensitivity("hybrid", "middle")
    assert 1e-8 < sensitivity < 1e-5                      # measured 2.0e-7: far above 1e-10
    assert _serial_ulp_sensitivity("hybrid", "structured") < 1e-10


@pytest.mark.parametrize("method,kind,n", [("fetidp", "structured", 2), ("bddc", "structured", 2),
                                           ("fetidp", "unstructured", 2), ("bddc", "unstructured", 3),
                                           ("feti", "structured", 3),
                                           ("feti-feti", "structured", 2), ("feti-feti", "middle", 4),
                                           ("feti-feti", "unstructured", 3),
                                           ("hybrid", "structured", 3), ("hybrid", "middle", 2),
                                           ("hybrid", "unstructured", 4)])
def test_distributed_equals_serial(tmp_path, method, kind, n):
    out_file = tmp_path / "u.npz"
    proc = mpiexec(n, [str(HERE / "mpi_case.py"), method, kind, str(out_file)])
    assert proc.returncode == 0, proc.stderr
    par = np.load(out_file)
    ser = _serial(method, kind)
    assert int(par["n_ranks"]) == n
    assert int(par["iterations"]) == ser.krylov.iterations
    tol = 1e-10
    if (method, kind) == ("hybrid", "middle"):
        # PCR on this indefinite system amplifies rounding (near-stagnating steps): the serial solver's own
        # answer moves by ~2e-7 when the load moves by one ulp. Agreement to that level is all any
        # implementation with another summation order can give (measured: 1.5e-7 on 1 rank, 2.0e-7 on 2).
        tol = max(tol, 4.0 * _serial_ulp_sensitivity(method, kind))
    assert np.linalg.norm(par["u"] - ser.u) <= tol * np.linalg.norm(ser.u)
    # the final error check (rho varies between subdomains in every case): the same estimate (BDDC: none).
    # It measures the error of u (1e-8 to 1e-6 here), so it moves with u: |eta(u1) - eta(u2)| is at most
    # ||u1 - u2|| in its own norm (measured: 0.05-0.3 times ||u1 - u2||_2 / ||u||_2, 1e-16 to 1.3e-7 here)
    estimate = float(par["error_estimate"])
    if method == "bddc":
        assert "error_estimate" not in ser.extra and np.isnan(estimate)
    else:
        assert 0 < ser.extra["error_estimate"] < 1e-4
        distance = np.linalg.norm(par["u"] - ser.u) / np.linalg.norm(ser.u)
        assert abs(estimate - ser.extra["error_estimate"]) <= 10 * distance + 1e-15
    if method == "hybrid":                      # PCR: no Lanczos estimate, in serial either
        assert ser.krylov.cond is None and np.isnan(par["cond"])
    else:
        assert abs(float(par["cond"]) - ser.krylov.cond) <= 1e-8 * ser.krylov.cond
    assert float(par["messages"]) > 0           # interface values did travel between the ranks


@pytest.mark.parametrize("kind,n", [("structured", 2), ("structured", 3), ("unstructured", 4)])
def test_distributed_active_set_equals_serial(tmp_path, kind, n):
    """Same outer steps, face-solve (PCR) and (5.4) PCG iterations, active set, solution and KKT residual."""
    from ddsolve.contact.run import contact_result_fields
    from ddsolve.spec import ProblemSpec

    out_file = tmp_path / "u.npz"
    proc = mpiexec(n, [str(HERE / "mpi_case.py"), "active-set", kind, str(out_file)])
    assert proc.returncode == 0, proc.stderr
    par = np.load(out_file)
    spec, scene = case("active-set", kind)
    prep = prepare(spec, scene)
    sol = SOLVERS["contact"]["active-set"](prep)
    ser = contact_result_fields(ProblemSpec.from_mapping(spec), prep.contact, sol)
    assert int(par["n_ranks"]) == n and bool(par["converged"]) and ser["converged"]
    assert int(par["outer"]) == sol.outer_iterations >= 1
    assert par["inner"].tolist() == list(sol.inner_iterations)
    assert int(par["pcg"]) == sol.pcg_iterations
    assert int(par["n_active"]) == ser["extra"]["n_active"]
    assert np.linalg.norm(par["u"] - sol.u) <= 1e-10 * np.linalg.norm(sol.u)
    assert abs(float(par["kkt"]) - ser["extra"]["kkt_residual"]) <= 1e-8 * ser["extra"]["kkt_residual"]
    assert float(par["messages"]) > 0


@pytest.mark.parametrize("rho", [[], ["--rho", "checkerboard:100"]])   # rho != 1: face_norm "scaled", c = 100
def test_cli_contact_json(rho):
    args = ["-m", "ddsolve", "solve", "--problem", "contact", "--method", "active-set", "--subdomains", "2",
            "--elements", "4", "--check", "--json", *rho]
    proc = mpiexec(2, args)
    assert proc.returncode == 0, proc.stderr
    import json
    summary = json.loads(proc.stdout)
    ref = json.loads(subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=TIMEOUT,
                                    env=mpi_env(), cwd=ROOT).stdout)
    assert set(ref) - set(summary) == set()                        # every serial key is reported
    for key in ("converged", "iterations", "outer_iterations", "inner_iterations", "pcg_iterations", "n_active",
                "n_contact", "nlambda"):
        assert summary[key] == ref[key], key
    # The KKT residual is what the face solve (rtol 1e-5) left over: with rho = 1 it agrees to 1e-8;
    # with a rho jump of 100 PCR amplifies the other summation order to ~1.5e-6 of it (measured).
    tol = 1e-8 if not rho else 1e-5
    assert abs(summary["kkt_residual"] - ref["kkt_residual"]) <= tol * ref["kkt_residual"]
    assert summary["error_vs_direct"] <= 1e-5 and summary["n_ranks"] == 2


def test_cli_json_contract():
    proc = mpiexec(2, ["-m", "ddsolve", "solve", "--subdomains", "4", "--elements", "4", "--cond", "--json"])
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 1                      # rank 0 alone prints
    import json
    summary = json.loads(lines[0])
    serial = subprocess.run([sys.executable, "-m", "ddsolve", "solve", "--subdomains", "4", "--elements", "4",
                             "--cond", "--json"], capture_output=True, text=True, timeout=TIMEOUT, env=mpi_env(),
                            cwd=ROOT)
    ref = json.loads(serial.stdout)
    assert "n_ranks" not in ref and "comm" not in ref
    assert summary["n_ranks"] == 2 and summary["iterations"] == ref["iterations"]
    assert abs(summary["cond"] - ref["cond"]) <= 1e-8 * ref["cond"]
    assert set(summary["comm"]) >= {"messages_per_iteration", "bytes_per_iteration", "allreduces_per_iteration",
                                    "coarse_seconds"}
    assert summary["comm"]["allreduces_per_iteration"] == 4.0      # 3 PCG reductions + 1 coarse rhs
    # two strips of 2 x 4 subdomains: 2 exchanges of the 4 x 3 dual multipliers on the cut, each way
    assert summary["comm"]["messages_per_iteration"] == 4.0
    assert summary["comm"]["bytes_per_iteration"] == 2 * 2 * 12 * 8
    assert 2 * messages_bytes(2, 8, 4)[1] == summary["comm"]["bytes_per_iteration"]      # the model's count
    assert summary["n_templates"] == 2 * ref["n_templates"]      # summed over ranks: each detects its own


@pytest.mark.parametrize("bodies, iterations, allreduces", [(3, 30, 8.0), (4, 37, 6.0)])
def test_hybrid_sums_paired_reductions_together(bodies, iterations, allreduces):
    """The hybrid PCR's Allreduces per iteration (floating bodies): PCR 3 (<A p, M A p>, ||r||, and <z, A z>
    with the pivot test's two norms in one), P^k of the operator (4.13) on its two blocks 1, P_R with P^k
    of the preconditioner (4.11) before and after its solves 2, the two coarse right-hand sides 2: 8, where
    each reduction alone made 13. With 4 x 4 bodies on 2 ranks each rank holds 8 whole bodies, so the coarse
    blocks (one per body) are each one rank's own and their right-hand sides are not summed: 6 (of 3 x 3
    bodies one is cut between the ranks). The iterations are the serial ones."""
    args = ["-m", "ddsolve", "solve", "--problem", "multibody", "--method", "hybrid", "--bodies", str(bodies),
            "--subdomains", "2", "--elements", "4", "--check", "--json"]
    proc = mpiexec(2, args)
    assert proc.returncode == 0, proc.stderr
    import json
    summary = json.loads(proc.stdout)
    ref = json.loads(subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=TIMEOUT,
                                    env=mpi_env(), cwd=ROOT).stdout)
    assert summary["n_floating"] > 0 and summary["iterations"] == ref["iterations"] == iterations
    assert summary["comm"]["allreduces_per_iteration"] == allreduces
    # the same error against the direct solution (3.9e-7 at rtol 1e-6), to the summation order
    assert abs(summary["error_vs_direct"] - ref["error_vs_direct"]) <= 1e-6 * ref["error_vs_direct"]


@pytest.mark.parametrize("method", ["feti-feti", "hybrid"])
def test_cli_multibody_metis_json(method):
    args = ["-m", "ddsolve", "solve", "--problem", "multibody", "--method", method, "--mesh", "unstructured",
            "--bodies", "2", "--parts", "3", "--maxh", "0.15", "--contact", "middle", "--json"]
    proc = mpiexec(2, args)
    assert proc.returncode == 0, proc.stderr
    import json
    summary = json.loads(proc.stdout)
    ref = json.loads(subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=TIMEOUT,
                                    env=mpi_env(), cwd=ROOT).stdout)
    assert summary["n_ranks"] == 2 and summary["iterations"] == ref["iterations"]
    assert summary["n_active"] == ref["n_active"] and summary["nlambda"] == ref["nlambda"]
    assert set(ref) - set(summary) == set()                        # every serial key is reported
    if method == "hybrid":
        assert summary["n_gamma"] == ref["n_gamma"] and summary["n_floating"] == ref["n_floating"]
    assert summary["timings"]["partition"] > 0.0                  # METIS timed apart from the mesh
    assert summary["n_templates"] == ref["n_templates"] == 12     # METIS parts: one template each


@pytest.mark.parametrize("problem", [[], ["--problem", "multibody", "--method", "feti-feti", "--bodies", "2"],
                                     ["--problem", "contact", "--method", "active-set"]])
def test_failure_on_one_rank_aborts_all(problem):
    proc = mpiexec(3, ["-m", "ddsolve", "solve", *problem, "--subdomains", "3", "--elements", "4", "--json"],
                    DDSOLVE_TEST_FAIL_RANK="1")
    assert proc.returncode != 0
    # exactly one error message, from the failing rank (count messages: the launcher may join lines)
    assert proc.stderr.count("ddsolve: error: ") == 1, proc.stderr
    assert ("ddsolve: error: rank 1: RuntimeError: injected failure (DDSOLVE_TEST_FAIL_RANK=1)\n"
            in proc.stderr), proc.stderr
    assert proc.stdout.strip() == ""


@pytest.mark.parametrize("method, geometry, parts", [("fetidp", "lshape", "6"), ("bddc", "hole", "4"),
                                                    ("feti", "hole", "4")])
def test_methods_without_interface_unknowns_as_serial(method, geometry, parts):
    """A tiny METIS scene with no interface unknowns (FETI-DP: every interface node primal; the hole at
    maxh 0.2: no free interface dof): solved directly, as serially (before, every rank aborted with
    "A: operator has size 0", FETI-DP a review, BDDC and FETI found after it, serially too)."""
    args = ["-m", "ddsolve", "solve", "--mesh", "unstructured", "--geometry", geometry, "--maxh", "0.3" if
            geometry == "lshape" else "0.2", "--parts", parts, "--method", method, "--check", "--json"]
    proc = mpiexec(2, args)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert result["nlambda"] == 0 and result["iterations"] == 0 and result["converged"]
    assert result["reason"].endswith("solved directly") and result["error_vs_direct"] < 1e-12


def test_interrupt_on_one_rank_ends_the_job():
    """Ctrl-C seen by one rank while the others wait in a collective ends every rank with status 130 (before,
    that rank returned 130 alone and the others waited forever; a review)."""
    proc = mpiexec(3, ["-m", "ddsolve", "solve", "--subdomains", "3", "--elements", "4", "--json"],
                    DDSOLVE_TEST_FAIL_RANK="1:interrupt")
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.count("ddsolve: interrupted (rank 1)") == 1, proc.stderr
    assert "ddsolve: error" not in proc.stderr and proc.stdout.strip() == ""


def test_ctrl_c_while_rank_0_alone_checks_ends_with_130(tmp_path):
    """SIGINT to mpiexec after the distributed solve, while rank 0 alone runs the --check reference: the job
    ended with status 2 (the other rank, exiting, died of the signal; 2 is an input error's status) and at
    times without the line (a review). The other ranks ignore SIGINT once done; rank 0 reports it."""
    import signal
    import subprocess
    import time

    from launch import MPIEXEC, ROOT, mpi_env

    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:
        proc = subprocess.Popen([MPIEXEC, "-n", "2", sys.executable, "-m", "ddsolve", "-v", "solve", "--problem",
                                 "contact", "--subdomains", "8", "--elements", "24", "--check", "--json"],
                                stdout=subprocess.DEVNULL, stderr=err, env=mpi_env(), cwd=ROOT)
        deadline = time.monotonic() + 100
        # rank 0 assembles the serial problem of the reference only after the distributed solve (-v logs it)
        while "assembled 128 subdomains" not in log.read_text() and time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.005)
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=60)
    text = log.read_text()
    assert code == 130, text
    assert text.count("ddsolve: interrupted (rank 0)") == 1, text


def test_sigterm_during_output_leaves_no_temporary_file(tmp_path):
    """SIGTERM to mpiexec while rank 0 writes --output: the temporary file was left in 5 of 5 runs with P = 2
    (the other rank ended at once and the launcher killed rank 0 before its handler ran; a review)."""
    import signal
    import subprocess
    import time

    from launch import MPIEXEC, ROOT, mpi_env

    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen([MPIEXEC, "-n", "2", sys.executable, "-m", "ddsolve", "solve", "--subdomains", "16",
                             "--elements", "24", "--output", str(out / "big.vtu"), "--json"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=mpi_env(), cwd=ROOT)
    deadline = time.monotonic() + 100
    while not list(out.glob(".big.*.tmp*")) and time.monotonic() < deadline:
        assert proc.poll() is None
        time.sleep(0.002)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=60)
    assert list(out.iterdir()) == []                 # neither the temporary file nor a partial target


@pytest.mark.parametrize("kind", ["", ":input"])
def test_an_error_on_every_rank_is_reported_once_per_rank(kind):
    """An error raised on every rank at once: MPICH may let MPI_Abort return on some ranks, which then
    printed their line a second time and went on (a review); one line per rank, and the job fails."""
    proc = mpiexec(2, ["-m", "ddsolve", "solve", "--subdomains", "2", "--elements", "4", "--json"],
                    DDSOLVE_TEST_FAIL_RANK="0,1" + kind)
    assert proc.returncode != 0
    assert proc.stderr.count("ddsolve: error: ") == 2, proc.stderr
    assert all(proc.stderr.count(f"ddsolve: error: rank {r}: ") == 1 for r in (0, 1)), proc.stderr
    assert proc.stdout.strip() == ""


@pytest.mark.parametrize("args,field", [(["--subdomains", "0"], "subdomains"),
                                        (["--method", "direct"], "method"),
                                        (["--problem", "contact", "--method", "smalbe"], "method"),
                                        (["--problem", "multibody", "--method", "hybrid", "--projection",
                                          "dirichlet"], "projection"),
                                        (["--problem", "multibody", "--method", "feti-feti", "--bodies", "3",
                                          "--subdomains", "1"], "subdomains")])
def test_bad_input_exits_2_on_every_rank(args, field):
    proc = mpiexec(2, ["-m", "ddsolve", "solve", *args])
    assert proc.returncode == 2, proc.stderr
    # one line per rank (the launcher may join two ranks' lines: count the messages, not the lines)
    assert proc.stderr.count("ddsolve: error: ") == 2, proc.stderr
    assert proc.stderr.count(f"ddsolve: error: {field}: ") == 2, proc.stderr


@pytest.mark.parametrize("failure", ['ImportError("mpi4py broken (test)")',
                                     'RuntimeError("libmpi cannot be loaded (test)")'])   # a broken MPI library
def test_without_mpi4py_is_a_clear_error(tmp_path, failure):
    broken = tmp_path / "mpi4py"
    broken.mkdir()
    (broken / "__init__.py").write_text(f"raise {failure}\n")
    proc = mpiexec(2, ["-m", "ddsolve", "solve", "--subdomains", "3", "--elements", "4"],
                    PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT), str(ROOT / "studies")]))
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("ddsolve: error: mpi: running under mpiexec with 2 ranks needs mpi4py") == 2
    assert proc.stderr.count("(test)") == 2 and "Traceback" not in proc.stderr


def test_serial_run_never_imports_mpi4py():
    code = ("import sys; from ddsolve.cli import main; main(['solve', '--subdomains', '2', '--elements', '2']); "
            "print('mpi4py' in sys.modules, 'ddsolve.parallel' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=TIMEOUT,
                          env={k: v for k, v in mpi_env().items() if k not in ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE",
                                                                             "PMIX_SIZE")}, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "False False"


def test_cli_contact_energy_fallback_equals_serial():
    """A METIS contact case whose first face solve breaks down on the thesis S~_OL (tests/unit/contact/test_s_ol.py):
    under mpiexec the fallback to the energy form happens on the same face, with the same iterations."""
    import json
    args = ["-m", "ddsolve", "solve", "--problem", "contact", "--mesh", "unstructured", "--geometry", "membranes",
            "--maxh", "0.1", "--refine", "1", "--parts", "64", "--json"]
    proc = mpiexec(2, args)
    assert proc.returncode == 0, proc.stderr
    par = json.loads(proc.stdout)
    ser = json.loads(subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=TIMEOUT,
                                    env=mpi_env(), cwd=ROOT).stdout)
    assert par["converged"] and ser["converged"] and "redone with s_ol='energy'" in ser["reason"]
    assert par["reason"] == ser["reason"]
    assert par["inner_iterations"] == ser["inner_iterations"] and par["n_active"] == ser["n_active"]
    assert abs(par["kkt_residual"] - ser["kkt_residual"]) <= 1e-8 * ser["kkt_residual"]


def test_distributed_hybrid_falls_back_to_the_energy_form_as_serial():
    """The multibody hybrid method's breakdown on S~_OL is redone with its energy form on every rank alike
    (tests/unit/multibody/test_hybrid_fallback.py is the serial side)."""
    import json

    args = ["-m", "ddsolve", "solve", "--problem", "multibody", "--method", "hybrid", "--mesh", "unstructured",
            "--geometry", "square", "--bodies", "2", "--maxh", "0.05", "--parts", "16", "--check", "--json"]
    proc = mpiexec(2, args)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["converged"] and out["s_ol"] == "energy", out["reason"]
    assert out["error_vs_direct"] < 1e-5                               # measured 2.5e-7


@pytest.mark.parametrize("args", [["--subdomains", "3", "--rho", "1e-307", "--f", "1e300"],
                                  ["--problem", "contact", "--subdomains", "2", "--elements", "4",
                                   "--rho", "checkerboard:1e300"]])
def test_an_overflow_is_reported_without_numpy_warnings(args):
    """inf + (-inf) in the neighbour sums and an overflow in the Krylov inner products printed numpy's
    RuntimeWarning, with its source line, from every rank (a review); the result says it instead."""
    proc = mpiexec(3, ["-m", "ddsolve", "solve", *args, "--json"])
    assert proc.returncode == 0, proc.stderr
    assert "RuntimeWarning" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    result = json.loads(proc.stdout)
    assert result["converged"] is False and "breakdown" in result["reason"], result["reason"]


@pytest.mark.parametrize("case, message", [("neg", "elements: id -1 is out of range [0, 25)"),
                                           ("dirichlet", "dirichlet: must be a bool array of shape (25,)")])
def test_a_users_scene_is_checked_whole_before_it_is_cut(case, message):
    """An element id of -1 in a scene given to ddsolve.parallel.run.solve was cut into a valid local id: 2 ranks
    solved another problem and reported it converged (serial refused it); an int dirichlet mask failed on rank 0
    alone with numpy's error while rank 1 waited in a broadcast (a review). Now every rank raises the InputError."""
    code = f"""
import dataclasses, numpy as np
from mpi4py import MPI
from ddsolve import ProblemSpec
from ddsolve.parallel.run import solve
from ddsolve.scene import structured_square
sc = structured_square(1, 2, 2)
sc.f = 1.0
if {case!r} == "neg":
    sc = dataclasses.replace(sc, elements=np.where(sc.elements == 0, -1, sc.elements))
else:
    sc = dataclasses.replace(sc, dirichlet=sc.dirichlet.astype(int))
lines = []
try:
    solve(ProblemSpec(method="fetidp"), scene=sc if MPI.COMM_WORLD.rank == 0 else None)
    lines.append("solved")
except Exception as e:
    lines.append(f"{{type(e).__name__}} {{e}}")
out = MPI.COMM_WORLD.gather(lines[0], root=0)
if MPI.COMM_WORLD.rank == 0:
    print("\\n".join(out))
"""
    proc = mpiexec(2, ["-c", code])
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 2 and all(line.startswith(f"InputError {message}") for line in lines), proc.stdout


@pytest.mark.parametrize("where", ["every", "root"])
def test_a_given_multibody_scene_is_tied_on_every_rank(tmp_path, where):
    """A multibody scene whose clamp ends at a point shared by two bodies: rank 0 ties the Dirichlet condition
    to every copy (ddsolve.prepared.tied_scene); a scene given on every rank was cut untied on the others and
    the run crashed in the substructures (found while fixing the serial defect)."""
    code = f"""
from mpi4py import MPI
from netgen.occ import Glue, MoveTo, OCCGeometry
from ddsolve import ProblemSpec
from ddsolve.parallel.run import solve
from ddsolve.scene.unstructured import scene_from_mesh
faces = []
for k, x in enumerate((0, 1)):
    face = MoveTo(x, 0).Rectangle(1, 1).Face()
    face.faces.name = f"b{{k}}"
    faces.append(face)
shape = Glue(faces)
for edge in shape.edges:
    edge.name = "clamp" if abs(edge.center.y) < 1e-9 and edge.center.x < 1 else "other"
scene = scene_from_mesh(OCCGeometry(shape, dim=2).GenerateMesh(maxh=0.25), dirichlet="clamp", parts=2)
spec = ProblemSpec(problem="multibody", method="feti-feti", mesh="unstructured", check=True, rtol=1e-10)
result = solve(spec, scene=scene if {where!r} == "every" or MPI.COMM_WORLD.rank == 0 else None)
if result is not None:
    print(result.converged, result.error_vs_direct)
"""
    proc = mpiexec(2, ["-c", code])
    assert proc.returncode == 0, proc.stderr
    converged, error = proc.stdout.split()
    assert converged == "True" and float(error) < 1e-8


@pytest.mark.parametrize("method, iterations", [("hybrid", 19), ("feti-feti", 9)])
def test_coarse_sums_over_the_ranks_sharing_a_block(tmp_path, method, iterations):
    """2 x 2 bodies of 2 x 2 subdomains on 5 ranks (subdomains 0-2, 3-5, 6-8, 9-11, 12-15): ranks 0-3 share
    bodies 0-2 and sum their coarse right-hand sides over a sub-communicator of 4 ranks; rank 4 holds body 3
    whole and sums nothing. The iterations and the error against the direct solution are the serial ones.
    (Each rank writes its own file: lines printed by 5 ranks to one stream came interleaved; a review.)"""
    args = ["-m", "ddsolve", "solve", "--problem", "multibody", "--method", method, "--bodies", "2",
            "--subdomains", "2", "--elements", "4", "--check", "--json"]
    code = f"""
import runpy, sys
from ddsolve.parallel import coarse
made = coarse.DistributedPrimalSolver._reduction_comm
def spy(self, *a):
    out = made(self, *a)
    with open(f"{tmp_path}/rank{{self.comm.rank}}.txt", "a") as fh:
        fh.write(f"{{None if out is None else out.size}}\\n")
    return out
coarse.DistributedPrimalSolver._reduction_comm = spy
sys.argv = ["ddsolve", *sys.argv[1:]]
runpy.run_module("ddsolve", run_name="__main__")
"""
    proc = mpiexec(5, ["-c", code, *args[2:]])
    assert proc.returncode == 0, proc.stderr
    sizes = {rank: set((tmp_path / f"rank{rank}.txt").read_text().split()) for rank in range(5)}
    assert sizes == {0: {"4"}, 1: {"4"}, 2: {"4"}, 3: {"4"}, 4: {"None"}}, sizes
    summary = json.loads(proc.stdout)
    ref = json.loads(subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=TIMEOUT,
                                    env=mpi_env(), cwd=ROOT).stdout)
    assert summary["iterations"] == ref["iterations"] == iterations
    assert abs(summary["error_vs_direct"] - ref["error_vs_direct"]) <= 1e-6 * ref["error_vs_direct"]
    # the largest over the ranks (rank 4 makes one coarse sum fewer): PCR 3 + 2 coarse, PCG 3 + 1 coarse
    assert summary["comm"]["allreduces_per_iteration"] == (5.0 if method == "hybrid" else 4.0)


def test_split_communicators_are_made_once_per_communicator():
    """CountingComm.split makes one MPI communicator per member pattern and communicator (a solver per face
    solve or per call would otherwise use up MPI's communicator ids), sums over its members only, and a
    communicator made after another was freed gets its own (a cache keyed by the handle returned the freed
    one's sub-communicator once MPI reused the handle: wrong sums and a hang; a review)."""
    code = """
import numpy as np
from mpi4py import MPI
from ddsolve.parallel import comm as C
w = MPI.COMM_WORLD
r = w.Get_rank()
cc = C.CountingComm(w)
subs = [cc.split((True, False, True)) for _ in range(3)]
made_once = all(s is None or s.comm is subs[0].comm for s in subs)
total = None if subs[0] is None else subs[0].allreduce_sum(np.array([r + 1.0]))[0]
rows = [f"world {r} once {made_once} sum {total} same counters {subs[0] is None or subs[0].counters is cc.counters}"]
for trial in range(4):                      # a new communicator after a freed one, over other ranks each time
    A = w.Split(0 if r != trial % 3 else MPI.UNDEFINED, r)
    if A != MPI.COMM_NULL:
        s = C.CountingComm(A).split((True, False))
        got = None if s is None else s.allreduce_sum(np.array([r + 1.0]))[0]
        rows.append(f"world {r} trial {trial} sum {got}")
        A.Free()
out = w.gather("\\n".join(rows), root=0)
if r == 0:
    print("\\n".join(out))
"""
    proc = mpiexec(3, ["-c", code])
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.split("\n")
    assert [line for line in lines if "once" in line] == [
        "world 0 once True sum 4.0 same counters True", "world 1 once True sum None same counters True",
        "world 2 once True sum 4.0 same counters True"], proc.stdout
    trials = sorted(line for line in lines if "trial" in line)
    # trial t leaves out world rank t % 3; of the other two, the lower is the member: it sums its own r + 1
    expected = sorted([f"world {r} trial {t} sum {float(r + 1) if r == min(set(range(3)) - {t % 3}) else None}"
                       for t in range(4) for r in range(3) if r != t % 3])
    assert trials == expected, proc.stdout
