"""The inexact body Schur complement S~_OL of the hybrid preconditioner (4.9)-(4.11) can be indefinite.

Smallest case found (999 dofs, 64 METIS parts per membrane): the thesis's form
S_GG - S_G0 M_0 S_0G has negative eigenvalues, the first active set face solve
breaks down in PCR, and the energy form E^T S E (PSD by construction) solves it.
"""
from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from ddsolve.contact import ContactProblem
from ddsolve.contact.active_set import ActiveSetHybrid, solve_contact_active_set
from ddsolve.contact.direct import solve_contact_direct
from ddsolve.dd import Substructures
from ddsolve.presets import solver_options
from ddsolve.scene import assemble
from ddsolve.scene.unstructured import unstructured_scene


@pytest.fixture(scope="module")
def case():
    with threadpool_limits(1, "blas"):
        scene = unstructured_scene("contact", geometry="membranes", maxh=0.1, refine=1, parts=64, seed=0)
        problem = ContactProblem(Substructures(assemble(scene)))
        solver = ActiveSetHybrid(problem)
        ref = solve_contact_direct(problem)
    assert ref.converged, ref.reason
    return problem, solver, ref


def dense(op, n):
    return np.column_stack([op(e) for e in np.eye(n)])


def test_thesis_form_is_indefinite_and_energy_form_is_psd(case):
    _, solver, _ = case
    h = solver.hybrid
    n = h.global_space.n
    with threadpool_limits(1, "blas"):
        S_thesis = dense(h.S_ol, n)
        S_energy = dense(h.S_ol_energy, n)
    for S in (S_thesis, S_energy):
        assert np.abs(S - S.T).max() <= 1e-12 * np.abs(S).max()
    ev_thesis = np.linalg.eigvalsh(S_thesis)
    ev_energy = np.linalg.eigvalsh(S_energy)
    scale = ev_thesis[-1]
    assert ev_thesis[0] < -0.1 * scale            # measured -0.78 (largest 2.87)
    assert ev_energy[0] >= -1e-12 * ev_energy[-1]  # measured 0.24 (largest 4.15)
    # the energy form is the quadratic form of the extension [v; -M_0 S_0G v]
    rng = np.random.default_rng(0)
    v = rng.standard_normal(n)
    w = h._local_solve(h.schur.space_matvec(v, h.global_space, h.local_space))
    energy = (v @ h.schur.space_matvec((v, -w), (h.global_space, h.local_space), h.global_space)
              - w @ h.schur.space_matvec((v, -w), (h.global_space, h.local_space), h.local_space))
    assert abs(v @ (S_energy @ v) - energy) <= 1e-10 * abs(energy)
    with pytest.raises(ValueError, match="s_ol"):
        h.inexact_schur("exact")


def _check_against_direct(problem, sol, ref):
    assert sol.converged, sol.reason
    np.testing.assert_array_equal(sol.active, ref.active)
    e, e_ref = problem.energy(sol.u), problem.energy(ref.u)
    assert abs(e - e_ref) <= 1e-8 * abs(e_ref)
    assert problem.kkt(sol.u, sol.lam).max <= 1e-8


def test_default_falls_back_to_the_energy_form(case):
    problem, solver, ref = case
    with threadpool_limits(1, "blas"):
        sol = solver.solve(rtol=1e-10)
    _check_against_direct(problem, sol, ref)
    assert sol.extra["s_ol_fallback"] == [1] and sol.extra["s_ol"] == "energy"
    assert sol.extra["s_ol_breakdown_iterations"][0] > 0
    assert "redone with s_ol='energy'" in sol.reason


def test_energy_form_forced(case):
    problem, solver, ref = case
    with threadpool_limits(1, "blas"):
        sol = solver.solve(rtol=1e-10, s_ol="energy")
    _check_against_direct(problem, sol, ref)
    assert sol.extra["s_ol_fallback"] == [] and sol.extra["s_ol"] == "energy"
    assert "redone" not in sol.reason
    with pytest.raises(ValueError, match="s_ol"):
        solver.solve(s_ol="exact")


@pytest.mark.parametrize("options", [{"s_ol_fallback": False}, "thesis-preset"])
def test_without_fallback_the_breakdown_is_reported(case, options):
    problem, solver, _ = case
    if options == "thesis-preset":
        options = solver_options("thesis", "contact", "active-set")
        assert options["s_ol_fallback"] is False
    with threadpool_limits(1, "blas"):
        sol = solve_contact_active_set(problem, rtol=1e-10, solver=solver, **options)
    assert not sol.converged
    assert sol.reason.startswith("face solve 1 did not converge: breakdown")
    assert "M not positive definite" in sol.reason
    assert sol.extra["s_ol_fallback"] == [] and sol.extra["s_ol"] == "thesis"
