"""Skip what a scene does not need: no floating bodies means no kernel or projector work."""
from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

import ddsolve.multibody.fetifeti as fetifeti_mod
from ddsolve.api import build_scene
from ddsolve.dd import Substructures
from ddsolve.dd.projection import Projection
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.fetifeti import FetiFetiSolver
from ddsolve.multibody.hybrid import HybridSolver
from ddsolve.scene import assemble
from ddsolve.spec import ProblemSpec


def layout(bodies: int):
    spec = ProblemSpec(problem="multibody", bodies=bodies, subdomains=2, elements=2)
    sub = Substructures(assemble(build_scene(spec)))
    return sub, GlobalInterface(sub)


@pytest.mark.parametrize("bodies, floating", [(2, 0), (3, 1)])
def test_projector_work_only_with_floating_bodies(monkeypatch, bodies, floating):
    sub, gi = layout(bodies)
    assert gi.floating_bodies().size == floating
    calls = {"GtG": 0, "G": []}
    orig_gtg = Projection.coarse_solve

    def counting_gtg(self, x):
        calls["GtG"] += 1
        return orig_gtg(self, x)

    orig_dual = fetifeti_mod.solve_dual

    def spy_dual(F, M, d, G, e, q, **kw):
        calls["G"].append(G)
        return orig_dual(F, M, d, G, e, q, **kw)

    monkeypatch.setattr(Projection, "coarse_solve", counting_gtg)
    monkeypatch.setattr(fetifeti_mod, "solve_dual", spy_dual)
    active = gi.contact_mask("full")
    with threadpool_limits(1, "blas"):
        hs = HybridSolver(sub, gi)
        out_h = hs.solve(active, rtol=1e-8)
        ff = FetiFetiSolver(sub, gi)
        out_f = ff.solve(active, rtol=1e-8)
    assert out_h.krylov.converged and out_f.krylov.converged
    if floating == 0:
        # no kernel: R_c has no column, P^k and P_R are the identity, G^T G is never solved
        assert ff.R.shape[1] == 0 and hs.active_set(active).projection.k == 0
        assert calls["GtG"] == 0 and calls["G"] == [None]
        u = np.random.default_rng(0).standard_normal(hs.n_gamma)
        assert hs.P_R(u) is u
    else:
        assert ff.R.shape[1] == floating and calls["GtG"] > 0 and calls["G"][0] is not None


@pytest.mark.parametrize("method", ["bddc", "feti", "fetidp"])
def test_a_scene_without_interface_unknowns_is_solved_directly(method):
    """The hole at maxh 0.2 in 4 METIS parts has 5 free dofs and none on the interface: no Krylov solve is
    needed (BDDC and FETI stopped with "A: operator has size 0"; FETI-DP already solved it directly)."""
    from ddsolve import solve

    res = solve(dict(mesh="unstructured", geometry="hole", maxh=0.2, parts=4, method=method, check=True))
    assert res.converged and res.iterations == 0 and res.reason.endswith("solved directly")
    assert res.error_vs_direct < 1e-12
