"""SMALBE answers a black-box review (2026-11-27) found reported converged.

* A soft checkerboard (rho 1 / 1e-6 across subdomains): SMALBE's active set was wrong (the equality
  solve on it, the polish, needed a negative multiplier), lambda 57% off and energy error 1e-2, at a KKT
  stationarity of 18 eps; it passed its stopping rule and acceptance check and was reported converged.
* rtol 0.5: a KKT residual of 0.74 reported converged (the active set method caps it at 1e-2).

Both are now converged=False with the reason; the references are the direct solver's (``--check``).
"""
from __future__ import annotations

import pytest

from ddsolve import solve


def _smalbe(**fields):
    return solve(dict(problem="contact", method="smalbe", check=True, **fields))


@pytest.mark.parametrize("subdomains, elements", [(4, 4), (8, 8)])
def test_a_wrong_active_set_is_not_converged(subdomains, elements):
    res = _smalbe(subdomains=subdomains, elements=elements, rho="checkerboard:1e-6")
    assert res.extra["lambda_error_vs_direct"] > 0.5               # the answer is wrong (measured 0.57-0.58)
    assert not res.converged
    assert "SMALBE's active set is not the solution's" in res.reason and "negative multiplier" in res.reason


def test_a_loose_rtol_does_not_accept_a_kkt_residual_above_one_percent():
    res = _smalbe(subdomains=4, elements=8, rtol=0.5)
    assert res.extra["kkt_residual"] > 0.1
    assert not res.converged
    assert "> 1.0e-02 = min(max(100 rtol, 1e-08), 0.01)" in res.reason


@pytest.mark.parametrize("rho", ["1", "checkerboard:1e4", "checkerboard:1e-4", "body-checkerboard:1e-6"])
def test_right_answers_stay_converged(rho):
    res = _smalbe(subdomains=4, elements=8, rho=rho)
    assert res.converged, res.reason
    assert res.extra["lambda_error_vs_direct"] < 1e-5
