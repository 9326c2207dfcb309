"""ddsolve.parallel.solve refuses what the command line refuses under mpiexec, on every rank and before any
communication (a review: a method that is not distributed made rank 0 raise KeyError while rank 1 waited in
a broadcast until killed; primal="vertices+edges" was ignored, giving the vertices-only cond)."""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch import HERE, MPI_MARKS, mpiexec  # noqa: E402

pytestmark = MPI_MARKS


def test_library_refuses_on_every_rank():
    names = {"direct": "method", "smalbe": "method", "edges": "primal", "lumped": "projection", "one": "subdomains"}
    proc = mpiexec(2, [str(HERE / "refusal_case.py"), *names])
    assert proc.returncode == 0, proc.stderr
    expected = sorted(f"{name} {rank} {field}" for name, field in names.items() for rank in (0, 1))
    assert sorted(proc.stdout.strip().splitlines()) == expected        # one InputError per spec and rank


def test_a_given_scene_is_not_judged_by_the_spec_decomposition():
    """With a scene, its parts decide: the spec's own subdomain count (here 1, too few for 2 ranks and for
    BDDC) refused a valid 2-part METIS scene (a review of the check added above)."""
    proc = mpiexec(2, [str(HERE / "refusal_case.py"), "scene"])
    assert proc.returncode == 0, proc.stderr
    # (the ranks' lines may interleave in the launcher's stream)
    assert "scene 0 solved True" in proc.stdout and proc.stdout.count("solved") == 2, proc.stdout


def test_hybrid_load_beyond_the_double_range_is_a_breakdown_on_every_rank():
    """As serial (tests/unit/multibody/test_multibody_review_20261128.py): converged false, exit 0; under
    mpiexec it was an abort with 'InputError: atol' on every rank."""
    import json

    proc = mpiexec(2, ["-m", "ddsolve", "solve", "--problem", "multibody", "--method", "hybrid", "--rho", "1e-20",
                       "--f", "1e300", "--json"])
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert not result["converged"] and result["reason"].startswith("breakdown: non-finite initial residual")
