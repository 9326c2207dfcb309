"""Input found by a review of the CLI's files (2026-11-27)."""
import numpy as np
import pytest

from ddsolve import ProblemSpec, solve
from ddsolve.dd.substructure import rho_powers
from ddsolve.errors import InputError


@pytest.mark.parametrize("digits", ["٤", "４", "1_0"])
def test_numbers_take_ascii_digits_only(digits):
    with pytest.raises(InputError, match="^elements: must be an integer"):
        ProblemSpec.from_mapping({"elements": digits})


def test_rho_powers_survive_an_overflowing_exponent():
    rho = np.array([1.0, 10.0, 10.0, 0.1])
    group = np.array([0, 0, 1, 1])
    np.testing.assert_array_equal(rho_powers(rho, 1e308, group, 2), [0.0, 1.0, 1.0, 0.0])
    np.testing.assert_allclose(rho_powers(rho, 2.0, group, 2), [1.0, 100.0, 100.0, 0.01])
    w = rho_powers(np.array([1e200, 1e-200]), 3.0, np.array([0, 0]), 1)       # 1e600 overflows: ratios kept
    np.testing.assert_allclose(w, [1.0, 0.0], atol=1e-300)


@pytest.mark.parametrize("problem, method", [("poisson", "fetidp"), ("multibody", "feti-feti")])
def test_gamma_1e308_solves(problem, method):
    """gamma log(rho) = inf: inf - inf gave NaN weights and a breakdown with RuntimeWarnings."""
    res = solve(ProblemSpec(problem=problem, method=method, gamma=1e308, rho="checkerboard:10", check=True))
    assert res.converged, res.reason
    assert res.error_vs_direct < 1e-5
