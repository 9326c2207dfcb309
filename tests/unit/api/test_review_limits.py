"""Refusals before netgen runs (a review of 2026-11-27: 10,000 unstructured bodies took 50 s and 540 MB
to mesh before 4 parts of 2 elements each were refused; --parts 1e9 was blamed on maxh)."""
import time

import pytest

from ddsolve import ProblemSpec, solve
from ddsolve.errors import InputError
from ddsolve.limits import check_resources


def test_more_parts_than_a_body_can_have_is_refused_before_meshing():
    spec = ProblemSpec(problem="multibody", method="feti-feti", mesh="unstructured", bodies=100, maxh=0.5)
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="^parts: 4 subdomains requested but each of the 10000 bodies"):
        check_resources(spec)
    assert time.perf_counter() - t0 < 10.0      # not meshed: meshing took 50 s (a bound for a shared machine)


def test_the_bound_admits_what_netgen_can_partition():
    # side 1/3 at maxh 0.34: netgen gives 2 triangles a body, so 2 parts a body are possible, 3 are not
    res = solve(ProblemSpec(problem="multibody", method="feti-feti", mesh="unstructured", bodies=3, maxh=0.34,
                            parts=2))
    assert res.converged
    with pytest.raises(InputError, match="^parts: 3 subdomains requested"):
        check_resources(ProblemSpec(problem="multibody", method="feti-feti", mesh="unstructured", bodies=3,
                                    maxh=0.34, parts=3))


@pytest.mark.parametrize("fields, named", [({"parts": 10 ** 9}, "parts"), ({"maxh": 1e-6}, "maxh"),
                                           ({"refine": 9, "maxh": 0.01}, "refine")])
def test_too_large_names_the_field_that_makes_it_so(fields, named):
    with pytest.raises(InputError, match=f"^{named}: problem too large"):
        check_resources(ProblemSpec(mesh="unstructured", method="bddc", **fields))


def test_the_setup_estimate_counts_netgen_meshing():
    """A review of 2026-11-28: maxh 0.004 on the hole took 48 s of netgen meshing (11.7 s idle at 10,000
    triangles/s) and was estimated at 0.15 s; the time limit could never see meshing. A mesh file is not meshed."""
    from ddsolve.limits import estimate
    spec = ProblemSpec(mesh="unstructured", geometry="hole", maxh=0.004, parts=16, method="fetidp")
    assert 8.0 < estimate(spec).setup_seconds < 20.0
    refined = ProblemSpec(mesh="unstructured", geometry="hole", maxh=0.016, refine=2, parts=16, method="fetidp")
    assert estimate(refined).setup_seconds < 0.2 * estimate(spec).setup_seconds     # meshed coarse, then refined
    with pytest.raises(InputError, match=r"^maxh: problem too large: ~1\.87e\+04 s of set-up estimated"):
        check_resources(ProblemSpec(mesh="unstructured", geometry="hole", maxh=1e-4, parts=16, method="fetidp"),
                        max_memory="1000 TiB")
