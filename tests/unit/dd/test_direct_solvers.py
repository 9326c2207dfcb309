"""The direct reference solvers: scale-invariant singularity tests, failures reported, not raised."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import ddsolve.contact.direct as contact_direct
from ddsolve.contact import ContactProblem
from ddsolve.dd import Substructures
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.direct import (
    RELATIVE_PIVOT_TOL,
    SingularMatrixError,
    factorize_spd,
    solve_constrained_direct,
)
from ddsolve.prepared import prepare
from ddsolve.scene import assemble
from ddsolve.scene.contact import two_membranes
from ddsolve.spec import ProblemSpec


def _laplacian(n: int, clamped: bool) -> sp.csr_matrix:
    """1-D Neumann Laplacian (singular, constants in the kernel), or clamped at one end."""
    main = np.full(n, 2.0)
    main[[0, -1]] = 1.0
    if clamped:
        main[0] = 2.0
    return sp.diags([-np.ones(n - 1), main, -np.ones(n - 1)], [-1, 0, 1], format="csr")


@pytest.mark.parametrize("jump", [1.0, 1e-12, 1e12, 1e-150, 1e150])
def test_factorize_spd_is_scale_invariant(jump):
    """Two decoupled blocks, one scaled by ``jump``: nonsingular stays solvable, singular is found."""
    good = sp.block_diag([_laplacian(20, True), jump * _laplacian(20, True)]).tocsr()
    x = np.random.default_rng(0).standard_normal(40)
    solve = factorize_spd(good, "singular")
    np.testing.assert_allclose(solve(good @ x), x, rtol=1e-8)
    bad = sp.block_diag([_laplacian(20, True), jump * _laplacian(20, False)]).tocsr()
    with pytest.raises(SingularMatrixError, match="floating"):
        factorize_spd(bad, "floating")
    # numerically (not exactly) singular: a Neumann block plus a tiny relative perturbation
    eps = sp.diags(np.r_[np.zeros(20), np.full(20, 1e-15 * jump)])
    with pytest.raises(SingularMatrixError, match=r"floating \(relative pivot"):
        factorize_spd((bad + eps).tocsr(), "floating")
    assert RELATIVE_PIVOT_TOL == 1e-12


@pytest.mark.parametrize("rho", [1.0, "body-checkerboard:1e12", "body-checkerboard:1e-12"])
def test_constrained_direct_reports_a_floating_body_without_raising(rho):
    """3 x 3 bodies: the centre one floats. Tied, it solves under any jump; untied, a reason."""
    spec = ProblemSpec.from_mapping({"problem": "multibody", "bodies": 3, "subdomains": 2, "elements": 2,
                                     "rho": rho})
    sub = prepare(spec).sub
    gi = GlobalInterface(sub)
    none = np.zeros(gi.n_gl, dtype=bool)              # no constraint: the floating bodies are free
    out = solve_constrained_direct(sub, gi, none)
    assert out.krylov is not None and not out.krylov.converged
    assert "floating body is not tied" in out.krylov.reason and "relative pivot" in out.krylov.reason
    active = gi.contact_mask(spec.contact)
    ok = solve_constrained_direct(sub, gi, active)
    assert ok.krylov is None
    # against the tied problem (active pairs merged into one dof) assembled and solved by scipy
    from scipy.sparse.linalg import spsolve

    from ddsolve.multibody.check import tied_substructures
    tied, dof_map = tied_substructures(sub, gi, active)
    u = spsolve(tied.global_matrix().tocsc(), tied.assemble_vector(tied.f_W))[dof_map]
    np.testing.assert_allclose(ok.u, u, rtol=0, atol=1e-12 * np.abs(u).max())     # measured 4e-16 - 2e-15


def _contact(**kw) -> ContactProblem:
    return ContactProblem(Substructures(assemble(two_membranes(2, 4, **kw))))


def test_contact_direct_claims_convergence_only_with_small_kkt(monkeypatch):
    p = _contact()
    ref = contact_direct.solve_contact_direct(p)
    assert ref.converged and p.kkt(ref.u, ref.lam).max <= contact_direct.KKT_TOL
    face = contact_direct.solve_face_direct

    def perturbed(problem, active, factorize=None):   # a face solver that is 1e-3 off
        u = face(problem, active, factorize)
        return u + 1e-3 * np.abs(u).max() * np.sin(np.arange(u.size))

    monkeypatch.setattr(contact_direct, "solve_face_direct", perturbed)
    bad = contact_direct.solve_contact_direct(p)
    assert not bad.converged
    assert bad.reason.startswith("KKT conditions (5.5) not met"), bad.reason


def test_contact_direct_face_failure_is_a_reason_not_a_traceback(monkeypatch):
    p = _contact()

    def singular(problem, active, factorize=None):
        raise SingularMatrixError("the floating membrane is not tied to the clamped one")

    monkeypatch.setattr(contact_direct, "solve_face_direct", singular)
    sol = contact_direct.solve_contact_direct(p)
    assert not sol.converged and sol.reason.startswith("face solve 1 failed")
    assert not np.any(np.isfinite(sol.u))
