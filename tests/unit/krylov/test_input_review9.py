"""Input handling of the Krylov solvers found by a review of the Python API (2026-11-27)."""
import numpy as np
import pytest

from ddsolve.errors import InputError
from ddsolve.krylov import pcg, pcr

A = np.diag([1.0, 2.0, 3.0])
b = np.ones(3)


@pytest.mark.parametrize("solver", [pcg, pcr])
def test_rtol_of_one_or_more_names_the_rule_that_stopped(solver):
    res = solver(A, b, rtol=2.0)
    assert res.converged and res.iterations == 0
    assert res.reason == ("converged: ||r0|| = 1.7e+00 <= rtol ||r0|| = 2 ||r0|| "
                          "(rtol >= 1 stops before the first step)")      # it read "<= atol = 0.0e+00"
    assert solver(A, b, atol=10.0).reason == "converged: ||r0|| = 1.7e+00 <= atol = 1.0e+01"


@pytest.mark.parametrize("kwargs, field", [({"callback": 5}, "callback"), ({"x0": ["a", "b", "c"]}, "x0")])
def test_bad_arguments_are_input_errors(kwargs, field):
    with pytest.raises(InputError, match=f"^{field}: must be"):
        pcg(A, b, **kwargs)
    with pytest.raises(InputError, match="^b: must be an array of numbers, got 'abc'"):
        pcg(A, "abc")
    assert pcg(A, [1, 2, 3], rtol=1e-12).converged                 # integers and lists are numbers


def test_a_breakdown_at_the_rounding_level_says_so():
    from ddsolve import ProblemSpec, prepare
    from ddsolve.dd import solve_feti
    p = prepare(ProblemSpec(subdomains=4, elements=8))
    kr = solve_feti(p.sub, rtol=1e-20).krylov
    assert not kr.converged and kr.reason.startswith("breakdown:")
    assert "rounding (a tolerance below the attainable accuracy), not the operator" in kr.reason
    indefinite = pcg(np.diag([1.0, -1.0, 2.0]), b, rtol=1e-8)
    assert indefinite.reason.startswith("breakdown") and "rounding" not in indefinite.reason
