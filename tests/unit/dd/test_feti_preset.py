"""The thesis preset of one-level FETI and FETI-FETI: the orthogonal projection P of (2.13).

The default under rho-scaling is the Q-weighted P = I - Q G (G^T Q G)^{-1} G^T; the preset's
P = I - G (G^T G)^{-1} G^T is symmetric with P G = 0. Both solve the same problem (checked
against the direct solve).
"""
from __future__ import annotations

import numpy as np
import pytest

import ddsolve.dd.dual as dual_mod
from ddsolve import ProblemSpec, solve
from ddsolve.dd import Substructures, solve_direct, solve_feti
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.fetifeti import FetiFetiSolver
from ddsolve.prepared import prepare
from ddsolve.presets import solver_options
from ddsolve.scene import assemble, structured_square


def captured_projection(monkeypatch):
    """Record (G passed to Projection, the Projection) of every projected dual solve."""
    seen: list = []
    original = dual_mod.Projection

    def spy(G, *args, **kw):
        out = original(G, *args, **kw)
        seen.append((G, out))
        return out

    monkeypatch.setattr(dual_mod, "Projection", spy)
    return seen


def dense_projection(proj) -> np.ndarray:
    return np.column_stack([proj.apply(e) for e in np.eye(proj.n)])


def check_orthogonal(G_used, proj, G_true):
    """The projection in lambda space is I - G (G^T G)^{-1} G^T: symmetric, P G = 0, G unscaled."""
    G_true = G_true.toarray()
    np.testing.assert_array_equal(G_used.toarray(), G_true)          # sq = 1: no Q-scaling
    P = dense_projection(proj)
    assert np.abs(P - P.T).max() <= 1e-13
    assert np.abs(P @ G_true).max() <= 1e-12 * np.abs(G_true).max()
    np.testing.assert_allclose(P @ P, P, atol=1e-12)


@pytest.mark.parametrize("rho", [1.0, "checkerboard:100"])
def test_feti_thesis_projection_is_orthogonal(monkeypatch, rho):
    sub = prepare(ProblemSpec(problem="poisson", method="feti", subdomains=4, elements=4, rho=rho)).sub
    seen = captured_projection(monkeypatch)
    out = solve_feti(sub, rtol=1e-10, **solver_options("thesis", "poisson", "feti"))
    B, _ = sub.jump_operators(np.ones(sub.n_W, dtype=bool))
    (G_used, proj), = seen
    check_orthogonal(G_used, proj, B @ sub.kernel_basis())
    ref = solve_direct(sub)
    A = sub.global_matrix()
    e = out.u - ref.u
    assert np.sqrt(e @ (A @ e)) <= 1e-8 * np.sqrt(ref.u @ (A @ ref.u))


def test_feti_default_projection_is_weighted_and_differs(monkeypatch):
    """At rho = 1 too, Q = diag(B_D B_D^T) is not a multiple of I (cross points): P is not symmetric."""
    sub = Substructures(assemble(structured_square(1, 4, 8)))
    seen = captured_projection(monkeypatch)
    default = solve_feti(sub, rtol=1e-6, cond=True)
    thesis = solve_feti(sub, rtol=1e-6, cond=True, projection="orthogonal")
    (G_default, _), (G_thesis, _) = seen
    assert not np.allclose(G_default.toarray(), G_thesis.toarray() * (G_default.toarray()[G_thesis.nonzero()]
                                                                       [0] / G_thesis.data[0]))
    # the measured counts of docs/methods.md ("The thesis preset"): 4 against 5 iterations
    assert (default.krylov.iterations, thesis.krylov.iterations) == (4, 5)
    assert thesis.krylov.lambda_max == pytest.approx(2.0954, abs=1e-3)
    assert default.krylov.lambda_max == pytest.approx(2.1166, abs=1e-3)
    with pytest.raises(ValueError, match="projection"):
        solve_feti(sub, projection="lumped")


def test_fetifeti_thesis_projection_is_orthogonal(monkeypatch):
    sub = prepare(ProblemSpec(problem="multibody", method="feti-feti", bodies=3, subdomains=2, elements=2,
                              rho="checkerboard:10")).sub
    gi = GlobalInterface(sub)
    active = gi.contact_mask("full")
    solver = FetiFetiSolver(sub, gi)
    seen = captured_projection(monkeypatch)
    out = solver.solve(active, rtol=1e-10, **solver_options("thesis", "multibody", "feti-feti"))
    import scipy.sparse as sp
    B_gl, _ = gi.operators(active)
    B = sp.vstack([solver.B_loc, B_gl]).tocsr()
    (G_used, proj), = seen
    check_orthogonal(G_used, proj, (B @ solver.R).tocsc())
    default = solver.solve(active, rtol=1e-10)
    assert np.linalg.norm(out.u - default.u) <= 1e-7 * np.linalg.norm(default.u)


def test_preset_through_the_api():
    """solve() passes the preset's options; the result records the preset."""
    spec = dict(problem="poisson", method="feti", subdomains=4, elements=8, cond=True)
    default = solve(spec)
    thesis = solve({**spec, "preset": "thesis"})
    assert default.extra["preset"] == "default" and thesis.extra["preset"] == "thesis"
    assert (default.iterations, thesis.iterations) == (4, 5)
    fetidp = [solve({**spec, "method": "fetidp", "preset": p}) for p in ("default", "thesis")]
    assert fetidp[0].iterations == fetidp[1].iterations and fetidp[0].cond == fetidp[1].cond
    assert ProblemSpec(preset="THESIS").preset == "thesis"
