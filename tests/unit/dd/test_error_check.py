"""The final error check of FETI and FETI-DP (ddsolve.dd.check): an upper bound of the energy error of u.

Found by the fifth black-box review: with multiplicity scaling and coefficient jumps the dual rule met
rtol while u was 26% (rtol 1e-4, jump 1e6) to 107% (rtol 1e-6, jump 1e12) off, reported converged.
"""
from __future__ import annotations

import numpy as np
import pytest

from ddsolve import ProblemSpec, solve
from ddsolve.dd.check import energy_error_estimate, error_check
from ddsolve.dd.operators import DirichletSchur, PrimalConstrainedSolver
from ddsolve.prepared import prepare


def _energy_error(spec: ProblemSpec, u: np.ndarray) -> float:
    prep = prepare(spec)
    A = prep.sub.global_matrix()
    f = prep.sub.assemble_vector(prep.sub.f_W)
    from scipy.sparse.linalg import spsolve

    exact = spsolve(A.tocsc(), f)
    e = u - exact
    return float(np.sqrt(e @ A @ e / (exact @ A @ exact)))


@pytest.mark.parametrize(("method", "jump", "rtol"), [("fetidp", 1e12, 1e-6), ("feti", 1e12, 1e-6),
                                                      ("fetidp", 1e6, 1e-4), ("feti", 1e6, 1e-4)])
def test_multiplicity_scaling_with_jumps_is_not_converged(method, jump, rtol):
    spec = ProblemSpec(method=method, subdomains=4, elements=6, rho=f"checkerboard:{jump:g}", scaling="multiplicity",
                       rtol=rtol)
    res = solve(spec)
    error = _energy_error(spec, res.u)
    assert error > 0.2                                        # the answer is wrong ...
    assert res.converged is False                             # ... and says so
    assert res.reason.startswith("the solution does not satisfy A u = f to the tolerance")
    assert error <= res.extra["error_estimate"] * (1 + 1e-6) <= 1.5 * error     # rho-scaled BDDC: a tight bound


@pytest.mark.parametrize("method", ["fetidp", "feti"])
@pytest.mark.parametrize("rtol", [1e-2, 1e-4, 1e-8])
@pytest.mark.parametrize("scaling", ["rho", "multiplicity"])
def test_a_correct_solve_passes_the_check(method, rtol, scaling):
    spec = ProblemSpec(method=method, subdomains=4, elements=6, rho="checkerboard:100" if scaling == "rho" else 1,
                       scaling=scaling, rtol=rtol)
    res = solve(spec)
    error = _energy_error(spec, res.u)
    assert res.converged, res.reason
    assert error < 5 * rtol
    if scaling == "multiplicity" and rtol <= 1e-3:   # one coefficient: robust, no check (needs_check) up to
        assert "error_estimate" not in res.extra      # rtol 1e-3, where its limit is capped at 0.1
        return
    if scaling == "multiplicity":
        assert error <= res.extra["error_estimate"] * (1 + 1e-6)
        return
    assert error <= res.extra["error_estimate"] * (1 + 1e-6) <= 2 * error + 1e-14


def test_bddc_has_no_check_and_a_zero_load_estimates_zero():
    assert "error_estimate" not in solve(ProblemSpec(method="bddc", subdomains=3, elements=4,
                                                     rho="checkerboard:10")).extra
    prep = prepare(ProblemSpec(method="fetidp", subdomains=3, elements=4, f=0))
    sub = prep.sub
    cache: dict = {}
    estimate = energy_error_estimate(sub, np.zeros(sub.ndof), PrimalConstrainedSolver(sub, sub.vertex, cache),
                                     DirichletSchur(sub, sub.interface, cache))
    assert estimate == 0.0
    assert error_check(0.0, 1e-6, "fetidp") == (True, "")
    assert error_check(np.inf, 1e-6, "fetidp")[0] is False


@pytest.mark.parametrize("load", [1e-300, 1e300])
@pytest.mark.parametrize("method", ["fetidp", "feti"])
def test_the_check_is_scale_free(method, load):
    """f^T u of a load of 1e-300 underflows to 0: the estimate read inf and a correct solve failed."""
    res = solve(ProblemSpec(method=method, subdomains=3, elements=4, f=load, rho="checkerboard:10"))
    ref = solve(ProblemSpec(method=method, subdomains=3, elements=4, f=1.0, rho="checkerboard:10"))
    assert res.converged, res.reason
    assert res.extra["error_estimate"] == pytest.approx(ref.extra["error_estimate"], rel=1e-12)


@pytest.mark.parametrize("field, value", [("f", 1e-320), ("rho", 1e-320), ("f", "dostal:-1e-320,-1")])
def test_subnormal_values_are_refused(field, value):
    """A load of 1e-320 (three significant digits) gave answers 11-13% off, reported converged."""
    from ddsolve.errors import InputError

    problem = "contact" if str(value).startswith("dostal") else "poisson"
    with pytest.raises(InputError, match=f"{field}: .* is below 2.23e-308, the smallest normal number"):
        ProblemSpec(problem=problem, **{field: value})
