"""The contact solvers' own functions apply the KKT acceptance rule of ddsolve.solve (a review:
solve_contact_active_set at rtol 0.5 returned a KKT residual of 0.42, lambda 200% off, converged;
SMALBE at eps 0.5 without polish 0.93), and a tolerance outside (0, 1) is refused."""
import numpy as np
import pytest

from ddsolve import ProblemSpec, prepare
from ddsolve.contact import solve_contact_active_set, solve_contact_direct, solve_contact_smalbe
from ddsolve.contact.problem import kkt_limit
from ddsolve.errors import InputError


@pytest.fixture(scope="module")
def problem():
    return prepare(ProblemSpec(problem="contact", subdomains=2, elements=4)).contact


@pytest.mark.parametrize("solve", [lambda p: solve_contact_active_set(p, rtol=0.5),
                                   lambda p: solve_contact_smalbe(p, eps=0.5, polish=False)],
                         ids=["active-set", "smalbe"])
def test_loose_tolerance_is_not_accepted(problem, solve):
    sol = solve(problem)
    kkt = problem.kkt(sol.u, sol.lam).max
    assert kkt > kkt_limit(0.5) == 1e-2
    assert not sol.converged
    assert sol.reason.startswith("not accepted") and f"{kkt:.1e} > 1.0e-02" in sol.reason


def test_default_tolerance_is_accepted(problem):
    ref = solve_contact_direct(problem)
    for sol in (solve_contact_active_set(problem), solve_contact_smalbe(problem)):
        assert sol.converged, sol.reason
        assert problem.kkt(sol.u, sol.lam).max <= kkt_limit(1e-5)
        assert np.linalg.norm(sol.lam - ref.lam) <= 1e-4 * np.linalg.norm(ref.lam)


@pytest.mark.parametrize("kwargs, field", [({"rtol": 1.5}, "rtol"), ({"rtol": 0.0}, "rtol"),
                                           ({"pcg_rtol": float("nan")}, "pcg_rtol")])
def test_active_set_refuses_tolerances_outside_the_unit_interval(problem, kwargs, field):
    with pytest.raises(InputError, match=f"^{field}: must be in \\(0, 1\\)"):
        solve_contact_active_set(problem, **kwargs)


def test_active_set_refuses_a_forcing_term_outside_the_unit_interval(problem):
    from ddsolve.contact import ActiveSetHybrid
    with pytest.raises(InputError, match="^forcing: must be in"):
        ActiveSetHybrid(problem).solve(forcing=2.0)


def test_smalbe_reports_eps_outside_the_unit_interval(problem):
    sol = solve_contact_smalbe(problem, eps=1.5)          # its documented contract: reported, not raised
    assert not sol.converged and "eps must be a number in (0, 1)" in sol.reason


def test_an_overflowing_dual_operator_is_a_breakdown_not_an_input_error():
    """rho = 2.3e-308 is accepted input; F overflows in SMALBE's norm estimate, whose new finiteness check
    raised InputError('A: ...') out of ddsolve.solve (exit 2) where a breakdown is reported (a review)."""
    import warnings

    from ddsolve import solve
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = solve(ProblemSpec(problem="contact", method="smalbe", subdomains=2, elements=4, rho=2.3e-308))
    assert not res.converged and res.reason.startswith("numerical breakdown in smalbe")


@pytest.mark.parametrize("method", ["active-set", "smalbe"])
def test_the_solvers_kkt_residuals_are_those_of_the_result_and_reused(method, monkeypatch):
    """The solver functions return the residuals of their verdict (ContactSolution.kkt), of the (u, lambda)
    they return; ddsolve.solve reports those instead of computing them once more."""
    import ddsolve
    from ddsolve.contact.problem import ContactProblem

    real = ContactProblem.kkt
    seen = []
    monkeypatch.setattr(ContactProblem, "kkt", lambda self, u, lam: seen.append((u, lam)) or real(self, u, lam))
    res = ddsolve.solve(ProblemSpec(problem="contact", method=method, subdomains=2, elements=4))
    assert res.converged
    returned = [lam for u, lam in seen if np.array_equal(u, res.u)]
    fresh = real(prepare(ProblemSpec(problem="contact", subdomains=2, elements=4)).contact, res.u, returned[-1])
    assert res.extra["kkt_residual"] == fresh.max and res.extra["kkt_stationarity"] == fresh.stationarity
    if method == "active-set":
        assert len(seen) == 1        # was 2: the solver's verdict and ddsolve.solve's fields
