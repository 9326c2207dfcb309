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
