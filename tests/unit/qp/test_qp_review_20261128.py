"""QP-layer defects a black-box review (2026-11-28) reproduced."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.linalg import LinearOperator

from ddsolve.errors import InputError
from ddsolve.qp import mprgp, smalbe


def test_complex_data_is_refused():
    """mprgp with a complex b and smalbe with a complex BE solved the real part's problem, reported converged."""
    n = 8
    A = np.diag(np.arange(1.0, n + 1))
    with pytest.raises(InputError, match="^b: complex values are not supported"):
        mprgp(A, np.ones(n) * (1 + 5j), -np.inf)
    with pytest.raises(InputError, match="^BE: complex operators are not supported"):
        smalbe(A, np.ones(n), 0.0, np.ones((1, n)) * (1 + 1j), np.array([1.0]))


def test_mprgp_with_zero_b_and_no_atol_is_refused():
    """b = 0 with the default rtol: the rule rtol ||b|| = 0 is met by no rounded gradient; the exact answer was
    reported as a breakdown 'unbounded feasible direction' (smalbe already refused this)."""
    rng = np.random.default_rng(0)
    n = 6
    Q = rng.standard_normal((n, n))
    A = Q @ Q.T + np.eye(n)
    lb = np.r_[1.0, np.full(n - 1, -np.inf)]
    with pytest.raises(InputError, match="^atol: b = 0 makes the stopping rule"):
        mprgp(A, np.zeros(n), lb)
    start = mprgp(A, np.zeros(n), 0.0)          # lb = 0: the start x = 0 is the solution, its gradient exactly 0
    assert start.converged and start.iterations == 0 and not start.x.any()   # (the active set method's zero load)
    res = mprgp(A, np.zeros(n), lb, atol=1e-12)
    g = A @ res.x
    assert res.converged and res.x[0] == pytest.approx(1.0) and g[0] >= 0 and np.abs(g[1:]).max() < 1e-10


def test_mprgp_checks_the_initial_gradient():
    """A NaN at the first product (the initial gradient) read as an unbounded problem."""
    n = 5
    A = np.diag(np.arange(1.0, n + 1))
    calls = [0]

    def matvec(v):
        calls[0] += 1
        out = A @ v
        if calls[0] == 1:
            out[0] = np.nan
        return out

    res = mprgp(LinearOperator((n, n), matvec=matvec, dtype=float), np.ones(n), 0.0, norm_A=5.0)
    assert not res.converged and "non-finite values (NaN or Inf) at the initial gradient" in res.reason


def test_smalbe_names_an_operator_without_a_transpose():
    n = 4
    BE = LinearOperator((1, n), matvec=lambda v: np.array([v.sum()]), dtype=float)
    with pytest.raises(InputError, match=r"^BE: the operator has no transpose \(rmatvec\)"):
        smalbe(np.diag([1.0, 2, 3, 4]), np.ones(n), 0.0, BE, np.array([1.0]))


@pytest.mark.parametrize("eps", [1.0, 2.0, 0.0, float("nan")])
def test_smalbe_eps_outside_0_1_is_refused(eps):
    """eps = 2 met the rule ||g^P|| <= eps ||b|| at the start and reported converged with x 15% off (a second
    review of 2026-11-28); eps must lie in (0, 1) as every relative tolerance of ddsolve."""
    n = 6
    A = np.diag(np.arange(1.0, n + 1))
    with pytest.raises(InputError, match="^eps: must be in \\(0, 1\\)"):
        smalbe(A, np.ones(n), 0.0, np.ones((1, n)), np.array([1.0]), eps=eps)
    assert smalbe(A, np.ones(n), 0.0, np.ones((1, n)), np.array([1.0]), eps=0.5).iterations >= 1
