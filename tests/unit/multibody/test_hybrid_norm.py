"""PCR's M-norm stopping rule and the rho-weighted projection of the hybrid method.

``ddsolve.krylov.pcr(norm="M")`` stops on ||r||_M = <r, M r>^(1/2), the norm PCR
minimises; ``HybridSolver.solve(norm=..., projection=...)`` threads it through the
hybrid method together with FETI's Q-weighted projection onto V^k = ker(G^kT). The
robust configuration (``norm="M"``, ``projection="lumped"``) must keep the iterations
of a coefficient jump within 1.5x those of rho = 1 with floating bodies, where the
thesis's configuration (||r||_2, orthogonal P^k) does not. All randomness is seeded.
"""
from __future__ import annotations

import importlib
from functools import lru_cache

import numpy as np
import pytest
import scipy.linalg as sla
from threadpoolctl import threadpool_limits

import ddsolve.multibody.hybrid as hybrid_module
import ddsolve.spec as spec_module
from ddsolve import ProblemSpec, solve
from ddsolve.api import build_scene
from ddsolve.dd import Substructures
from ddsolve.errors import InputError
from ddsolve.krylov import pcr
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.direct import solve_constrained_direct
from ddsolve.multibody.hybrid import PROJECTIONS, HybridSolver
from ddsolve.scene import assemble

pcr_module = importlib.import_module("ddsolve.krylov.pcr")

ROBUST = {"norm": "M", "projection": "lumped"}
THESIS = {"norm": "l2", "projection": "orthogonal"}


# --------------------------------------------------------------------------- #
# PCR in the M-norm
# --------------------------------------------------------------------------- #
def saddle(seed: int = 7, nk: int = 40, m: int = 10):
    """[[K, B^T], [B, 0]] (K SPD, B full row rank), a block SPD preconditioner, a load."""
    rng = np.random.default_rng(seed)
    q = rng.standard_normal((nk, nk))
    k = q @ q.T / nk + np.diag(rng.uniform(1.0, 6.0, nk))
    b = rng.standard_normal((m, nk))
    a = np.block([[k, b.T], [b, np.zeros((m, m))]])
    kinv = np.diag(1.0 / np.diag(k))
    prec = sla.block_diag(kinv, np.linalg.inv(b @ kinv @ b.T))
    f = rng.standard_normal(nk + m)
    return a, prec, f


def m_norm(prec: np.ndarray, r: np.ndarray) -> float:
    return float(np.sqrt(r @ (prec @ r)))


@pytest.mark.parametrize("pivot_tol", [None, 1.0])      # 1.0: the three-term recurrence from the start
def test_pcr_m_norm_matches_direct_solve(monkeypatch, pivot_tol):
    if pivot_tol is not None:
        monkeypatch.setattr(pcr_module, "_CR_PIVOT_TOL", pivot_tol)
    a, prec, f = saddle()
    x_ref = np.linalg.solve(a, f)
    res = pcr(a, f, rtol=1e-10, M=prec, norm="M")
    assert res.converged, res.reason
    assert "||r||_M" in res.reason
    assert np.linalg.norm(res.x - x_ref) <= 1e-8 * np.linalg.norm(x_ref)
    # residuals are ||r_k||_M: r_0 = f, monotone (Lemma 1.3.2), threshold met
    assert res.residuals[0] == pytest.approx(m_norm(prec, f), rel=1e-12)
    assert np.all(np.diff(res.residuals) <= 1e-12 * res.residuals[0])
    assert res.residuals[-1] <= 1e-10 * res.residuals[0]
    # the true residual is recomputed in the same norm
    assert res.true_residual == pytest.approx(m_norm(prec, f - a @ res.x), rel=1e-6)
    assert res.true_residual <= 10 * 1e-10 * res.residuals[0]


def test_pcr_m_norm_is_invariant_under_block_scaling():
    """D A D, D^{-1} M D^{-1}, D b with D = diag(s, 1/s): same ||r||_M history, unlike ||r||_2."""
    a, prec, f = saddle(seed=8)
    nk = a.shape[0] - 10
    ref = pcr(a, f, rtol=1e-8, M=prec, norm="M")
    for s in (1e-3, 1e3):
        d = np.r_[np.full(nk, s), np.full(10, 1.0 / s)]
        scaled = pcr(d[:, None] * a * d[None, :], d * f, rtol=1e-8, M=prec / d[:, None] / d[None, :], norm="M")
        assert scaled.converged and abs(scaled.iterations - ref.iterations) <= 1
        k = min(ref.iterations, scaled.iterations, 10)
        np.testing.assert_allclose(scaled.residuals[:k], ref.residuals[:k], rtol=1e-6)
        np.testing.assert_allclose(d * scaled.x, ref.x, rtol=0, atol=1e-6 * np.abs(ref.x).max())


def test_pcr_m_norm_projected_and_errors():
    a, prec, f = saddle(seed=9)
    n = a.shape[0]
    g = np.random.default_rng(9).standard_normal((n, 2))
    proj = np.eye(n) - g @ np.linalg.solve(g.T @ g, g.T)
    res = pcr(a, proj @ f, rtol=1e-10, M=prec, P=proj, norm="M")
    assert res.converged, res.reason
    assert np.linalg.norm(proj @ (f - a @ res.x)) <= 1e-8 * np.linalg.norm(proj @ f)
    with pytest.raises(ValueError, match="norm"):
        pcr(a, f, M=prec, norm="energy")
    # an indefinite preconditioner is a breakdown, never a convergence
    bad = pcr(a, f, M=-prec, norm="M")
    assert not bad.converged and bad.reason.startswith("breakdown") and "\n" not in bad.reason
    assert np.all(np.isfinite(bad.residuals))
    # l2 stays the default and scipy's call shape keeps working
    assert pcr(a, f, None, rtol=1e-8, M=prec).reason.startswith("converged: ||r||/||r0||")


# --------------------------------------------------------------------------- #
# hybrid method
# --------------------------------------------------------------------------- #
@lru_cache(maxsize=None)
def hybrid(nb: int, ns: int, m: int, rho: str | float, scaling: str = "rho"):
    """(sub, gi, solver) of problem (4.32), contact 'full', seeded load (random:0)."""
    spec = ProblemSpec.from_mapping({"problem": "multibody", "method": "hybrid", "bodies": nb, "subdomains": ns,
                                     "elements": m, "rho": rho, "scaling": scaling})
    sub = Substructures(assemble(build_scene(spec)), scaling=spec.scaling, gamma=spec.gamma)
    gi = GlobalInterface(sub)
    with threadpool_limits(1, "blas"):
        return sub, gi, HybridSolver(sub, gi)


def iterations(nb: int, ns: int, m: int, rho: str | float, **options) -> int:
    _, gi, hs = hybrid(nb, ns, m, rho)
    with threadpool_limits(1, "blas"):
        out = hs.solve(gi.contact_mask("full"), rtol=1e-6, **options)
    assert out.krylov.converged, out.krylov.reason
    return out.krylov.iterations


@pytest.mark.parametrize("projection", PROJECTIONS)
@pytest.mark.parametrize("contact", ["full", "middle"])
def test_hybrid_m_norm_matches_direct(projection, contact):
    sub, gi, hs = hybrid(3, 2, 3, "checkerboard:1e3")
    active = gi.contact_mask(contact)
    with threadpool_limits(1, "blas"):
        out = hs.solve(active, rtol=1e-10, norm="M", projection=projection)
    kr = out.krylov
    assert kr.converged and "||r||_M" in kr.reason, kr.reason
    assert kr.true_residual <= 10 * 1e-10 * kr.residuals[0]
    ref = solve_constrained_direct(sub, gi, active).u
    A = sub.global_matrix()
    e = out.u - ref
    assert np.sqrt(e @ (A @ e)) <= 1e-8 * np.sqrt(ref @ (A @ ref))
    # no jump on the active pairs; lambda balances S^ u - g^ (the first equation of (4.2))
    a = hs.active_set(active)
    u_g = out.extra["u_gamma"]
    assert np.abs(a.jump.matvec(u_g)).max() <= 1e-8 * np.abs(u_g).max()
    resid = hs.g_hat - hs.S_hat(u_g) - hs.jump_transpose(a, out.extra["lambda"])
    assert np.abs(resid).max() <= 1e-7 * np.abs(hs.g_hat).max()


@pytest.mark.parametrize("projection", ["dirichlet", "lumped"])
def test_weighted_projection_properties(projection):
    """P = I - QG(G^T Q G)^{-1} G^T: a projection onto ker(G^T), P^T kills range(G), Q P^T symmetric."""
    _, gi, hs = hybrid(4, 2, 2, "checkerboard:1e4")
    a = hs.active_set(gi.contact_mask("full"))
    proj = hs.projection(a, projection)
    n = a.n_active
    eye = np.eye(n)
    P = np.column_stack([proj.apply(e) for e in eye])
    PT = np.column_stack([proj.apply_transpose(e) for e in eye])
    G = a.G.toarray()
    np.testing.assert_allclose(PT, P.T, atol=1e-12)
    np.testing.assert_allclose(P @ P, P, atol=1e-10)
    assert np.abs(G.T @ P).max() <= 1e-10 * np.abs(G).max()
    assert np.abs(PT @ G).max() <= 1e-10
    Q = np.column_stack([(hs.M_D if projection == "dirichlet" else hs.M_lumped)(a, e) for e in eye])
    QPT = Q @ PT
    np.testing.assert_allclose(QPT, QPT.T, atol=1e-10 * np.abs(Q).max())
    assert hs.projection(a, "orthogonal") is a.projection and a.projection.orthogonal
    assert hs.projection(a, projection) is proj                     # cached on the active set
    with pytest.raises(ValueError, match="projection"):
        hs.projection(a, "oblique")


@pytest.mark.parametrize("rho", ["checkerboard:1e-4", "checkerboard:1e4", "body-checkerboard:1e-4",
                                 "body-checkerboard:1e6"])
def test_rho_scaling_robust_with_floating_bodies(rho):
    """4 floating bodies: the robust configuration stays within 1.5x the iterations of rho = 1."""
    base = iterations(4, 2, 2, 1.0, **ROBUST)
    assert iterations(4, 2, 2, rho, **ROBUST) <= 1.5 * base


def test_thesis_configuration_is_not_robust_with_floating_bodies():
    """What the robust configuration fixes: ||r||_2 and the orthogonal P^k need > 2x."""
    base = iterations(4, 2, 2, 1.0, **THESIS)
    assert iterations(4, 2, 2, "checkerboard:1e-6", **THESIS) > 2 * base
    # the projection matters, not only the stopping norm
    assert iterations(4, 2, 2, "checkerboard:1e-6", norm="M") > 1.5 * iterations(4, 2, 2, 1.0, norm="M")


def test_multiplicity_scaling_still_fails():
    """Theory: without rho-scaling the preconditioner degrades (indefinite across a checkerboard)."""
    _, gi, hs = hybrid(4, 2, 2, "checkerboard:1e4", "multiplicity")
    with threadpool_limits(1, "blas"):
        out = hs.solve(gi.contact_mask("full"), rtol=1e-6, **ROBUST)
    assert not out.krylov.converged and out.krylov.reason.startswith("breakdown")
    _, gi, hs = hybrid(4, 2, 2, "body-checkerboard:1e4", "multiplicity")
    with threadpool_limits(1, "blas"):
        out = hs.solve(gi.contact_mask("full"), rtol=1e-6, maxiter=2000, **ROBUST)
    assert out.krylov.converged
    assert out.krylov.iterations > 2 * iterations(4, 2, 2, 1.0, **ROBUST)


# --------------------------------------------------------------------------- #
# ProblemSpec keys
# --------------------------------------------------------------------------- #
def test_spec_keys():
    base = {"problem": "multibody", "method": "hybrid", "bodies": 3, "subdomains": 2, "elements": 2}
    spec = ProblemSpec.from_mapping({**base, "norm": "m", "projection": "Lumped"})
    assert (spec.norm, spec.projection) == ("M", "lumped")
    default = ProblemSpec.from_mapping(base)
    assert (default.norm, default.projection) == ("l2", "orthogonal")
    for field, value in (("norm", "l1"), ("norm", 2), ("projection", "oblique")):
        with pytest.raises(InputError, match=rf"^{field}: ") as exc:
            ProblemSpec.from_mapping({**base, field: value})
        assert "\n" not in str(exc.value)
    assert spec_module.NORMS == pcr_module.NORMS == hybrid_module.NORMS
    assert spec_module.PROJECTIONS == hybrid_module.PROJECTIONS
    _, gi, hs = hybrid(3, 2, 2, 1.0)
    with pytest.raises(ValueError, match="projection"):
        hs.solve(gi.contact_mask("full"), projection="oblique")
    with pytest.raises(ValueError, match="norm"):
        hs.solve(gi.contact_mask("full"), norm="max")
    with pytest.raises(InputError, match="^norm: .*hybrid"):
        ProblemSpec.from_mapping({"method": "fetidp", "norm": "M"})
    with pytest.raises(InputError, match="^projection: .*hybrid"):
        ProblemSpec.from_mapping({**base, "method": "feti-feti", "projection": "dirichlet"})
    res = solve(ProblemSpec.from_mapping({**base, "rho": "checkerboard:1e4", "norm": "M", "projection": "lumped",
                                          "check": True}))
    assert res.converged and "||r||_M" in res.reason
    assert res.error_vs_direct < 1e-4
