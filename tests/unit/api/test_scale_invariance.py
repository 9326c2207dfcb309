"""Scale invariance of every method: rho -> s rho, f -> t f gives u -> (t/s) u, the same iteration counts.

The discrete problems are linear in f and homogeneous of degree -1 in rho, so
an exact solver returns ``(t/s) u`` and a Krylov method that measures relative
residuals takes the same iterations (up to rounding: +-1). ``s`` and ``t`` run
over 1e-150..1e150 (``t/s`` over 1e-300..1e300), so squared norms and inner
products of the unscaled quantities would underflow or overflow. Seeded
examples (``derandomize=True``) keep the test deterministic and fast.

Contact multipliers scale like the load: lambda -> t lambda.
"""
from __future__ import annotations

import functools
import warnings

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from ddsolve.contact.run import run_contact_method
from ddsolve.dd import solve_bddc, solve_direct, solve_feti, solve_fetidp
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.direct import solve_constrained_direct
from ddsolve.multibody.fetifeti import FetiFetiSolver
from ddsolve.multibody.hybrid import HybridSolver
from ddsolve.prepared import prepare, scene_from_spec
from ddsolve.spec import ProblemSpec

RTOL = 1e-8
MAXITER = 500
SPECS = {
    "poisson": {"subdomains": 3, "elements": 4, "rho": "checkerboard:100", "f": "random:3"},
    "multibody": {"problem": "multibody", "bodies": 2, "subdomains": 2, "elements": 3,
                  "rho": "body-checkerboard:100"},
    "contact": {"problem": "contact", "method": "direct", "subdomains": 2, "elements": 4},
}
_POISSON = {"fetidp": solve_fetidp, "feti": solve_feti, "bddc": solve_bddc}

MPRGP_XFAIL = ("ddsolve/qp/mprgp.py (branch core) is not scale-invariant: its curvatures d^T A d overflow "
               "for lambda ~ 1e150 (maxiter reached) and underflow for lambda ~ 1e-150 ('beta^T A beta <= 0' "
               "breakdown), and SMALBE's eps ||b|| underflows to 0 at t/s = 1e-300")
CASES = [
    ("poisson", "fetidp"), ("poisson", "feti"), ("poisson", "bddc"), ("poisson", "direct"),
    ("multibody", "feti-feti"), ("multibody", "hybrid"), ("multibody", "direct"),
    pytest.param("contact", "active-set", marks=pytest.mark.xfail(strict=True, reason=MPRGP_XFAIL)),
    pytest.param("contact", "smalbe", marks=pytest.mark.xfail(strict=True, reason=MPRGP_XFAIL)),
    ("contact", "direct"),
]


def _solve(problem: str, method: str, s: float, t: float, norm: str = "M"):
    """(u, lambda or None, iteration counts, converged, reason) of the problem with rho*s, f*t."""
    spec = ProblemSpec.from_mapping(SPECS[problem])
    scene = scene_from_spec(spec)
    scene.rho = np.asarray(scene.rho, dtype=float) * s
    scene.f = scene.f * t
    prepared = prepare(spec, scene=scene)
    sub = prepared.sub
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        if problem == "contact":
            sol = run_contact_method(method, prepared.contact, rtol=RTOL, maxiter=MAXITER)
            return sol.u, sol.lam, (sol.total_iterations, sol.outer_iterations), sol.converged, sol.reason
        if problem == "poisson":
            out = (solve_direct(sub) if method == "direct"
                   else _POISSON[method](sub, rtol=RTOL, maxiter=MAXITER, cond=False))
        else:
            gi = GlobalInterface(sub)
            active = gi.contact_mask(spec.contact)
            if method == "direct":
                out = solve_constrained_direct(sub, gi, active)
            elif method == "feti-feti":
                out = FetiFetiSolver(sub, gi).solve(active, rtol=RTOL, maxiter=MAXITER, cond=False)
            else:
                out = HybridSolver(sub, gi).solve(active, rtol=RTOL, maxiter=MAXITER, norm=norm)
    kr = out.krylov
    if kr is None:
        return out.u, None, (0,), True, "direct solve"
    return out.u, None, (kr.iterations,), kr.converged, kr.reason


@functools.cache
def _reference(problem: str, method: str, norm: str = "M"):
    return _solve(problem, method, 1.0, 1.0, norm)


def _check(problem: str, method: str, s: float, t: float, norm: str = "M") -> None:
    u0, lam0, it0, conv0, _ = _reference(problem, method, norm)
    assert conv0
    u, lam, it, conv, reason = _solve(problem, method, s, t, norm)
    assert conv, reason
    assert np.all(np.abs(np.subtract(it, it0)) <= 1), (it, it0)
    assert np.all(np.isfinite(u))
    # compare u (s/t) with u0: the scaled solution, unscaled exactly enough (s/t is within range)
    err = np.linalg.norm(u * (s / t) - u0) / np.linalg.norm(u0)
    assert err < 1e-5, err
    if lam0 is not None:
        assert np.linalg.norm(lam / t - lam0) / np.linalg.norm(lam0) < 1e-5


EXPONENT = st.integers(min_value=-150, max_value=150)


@pytest.mark.parametrize(("problem", "method"), CASES)
@settings(max_examples=3, derandomize=True, deadline=None, database=None)
@given(es=EXPONENT, et=EXPONENT)
@example(es=150, et=-150)
@example(es=-150, et=150)
def test_scale_invariance(problem: str, method: str, es: int, et: int) -> None:
    _check(problem, method, 10.0 ** es, 10.0 ** et)


@settings(max_examples=3, derandomize=True, deadline=None, database=None)
@given(et=EXPONENT)
@example(et=150)
@example(et=-150)
def test_hybrid_l2_norm_invariant_under_load_scaling(et: int) -> None:
    """The default ||.||_2 rule of the hybrid adds forces (~ rho) to displacements (~ 1/rho), so it is
    invariant under f -> t f only (rho scaling changes the blocks' weights; norm="M" is invariant)."""
    _check("multibody", "hybrid", 1.0, 10.0 ** et, norm="l2")


def test_cli_rho_1e170_is_not_converged_at_zero_iterations() -> None:
    """The adversarial case: ||r0||^2 underflowed at rho = 1e170, reported converged after 0 iterations."""
    import ddsolve

    res = ddsolve.solve(ProblemSpec.from_mapping({"subdomains": 4, "elements": 4, "rho": 1e170, "check": True}))
    ref = ddsolve.solve(ProblemSpec.from_mapping({"subdomains": 4, "elements": 4, "check": True}))
    assert res.converged and res.iterations == ref.iterations > 0
    assert res.error_vs_direct < 1e-6


def test_multibody_direct_with_body_jump_1e12_solves() -> None:
    """The singularity test of the direct solvers is relative: a 1e12 jump between bodies is not 'floating'."""
    import ddsolve

    res = ddsolve.solve(ProblemSpec.from_mapping({"problem": "multibody", "method": "direct", "bodies": 2,
                                                  "rho": "body-checkerboard:1e12"}))
    assert res.converged and np.all(np.isfinite(res.u))
    hyb = ddsolve.solve(ProblemSpec.from_mapping({"problem": "multibody", "method": "hybrid", "norm": "M",
                                                  "bodies": 2, "rho": "body-checkerboard:1e12", "rtol": 1e-10}))
    assert np.linalg.norm(hyb.u - res.u) / np.linalg.norm(res.u) < 1e-6
