"""Weighted edge averages (ddsolve.dd.edges, "Weighted edges"): u_E = sum_j w_j u_j / sum_j w_j."""
from __future__ import annotations

import numpy as np
import pytest

from ddsolve.api import build_scene
from ddsolve.dd import Substructures
from ddsolve.dd.bddc import solve_bddc
from ddsolve.dd.direct import solve_direct
from ddsolve.dd.fetidp import solve_fetidp
from ddsolve.scene import assemble
from ddsolve.spec import ProblemSpec

SOLVERS = {"fetidp": solve_fetidp, "bddc": solve_bddc}


def _sub(weights=None, ns=3, m=5, rho="checkerboard:100"):
    local = assemble(build_scene(ProblemSpec.from_mapping({"subdomains": ns, "elements": m, "rho": rho,
                                                                 "f": "random:1"})))
    sub = Substructures(local, primal="vertices+edges")
    if weights is not None:
        sub.edge_weights = weights(sub.scene.n_nodes)
    return sub


def _random_weights(n):
    """Seeded weights of both signs, every third node's zero (like odd edge bubbles)."""
    w = np.random.default_rng(7).uniform(0.2, 1.0, n) * np.where(np.arange(n) % 5 == 1, -1.0, 1.0)
    w[np.arange(n) % 3 == 0] = 0.0
    return w


def test_unit_weights_give_the_unweighted_basis():
    plain = _sub()
    unit = _sub(np.ones)
    np.testing.assert_array_equal(unit.edges.representative, plain.edges.representative)
    d = unit.primal_space().T_W - plain.primal_space().T_W
    assert d.count_nonzero() == 0
    assert plain.edges.coef is None and plain.edges.anchor_entry is None


def test_weighted_columns():
    sub = _sub(_random_weights)
    edges, T = sub.edges, sub.primal_space().T_W.toarray()
    w_W = sub.edge_weights[sub.node_of_W]
    assert edges.n_edges == 12
    for e in range(edges.n_edges):
        for s in np.unique(sub.sub_of_W[edges.label == e]):
            on = np.flatnonzero((edges.label == e) & (sub.sub_of_W == s))
            rep = on[edges.representative[on]]
            assert rep.size == 1 and w_W[rep[0]] != 0               # the representative carries weight
            assert sub.node_of_W[rep[0]] == sub.node_of_W[on][w_W[on] != 0].min()
            wT = w_W[on] @ T[on]                                      # w^T T on this copy of the edge
            np.testing.assert_allclose(wT[rep[0]], w_W[on].sum(), rtol=1e-14)
            others = np.setdiff1d(on, rep)
            np.testing.assert_allclose(wT[others], 0.0, atol=1e-14)
            # the representative's new variable is the weighted average of u on the edge
            u = np.random.default_rng(int(e)).standard_normal(sub.n_W)
            u_hat = np.linalg.solve(T, u)
            np.testing.assert_allclose(u_hat[rep[0]], w_W[on] @ u[on] / w_W[on].sum(), rtol=1e-10)
    # T is the same function of the global node values on every copy: one (anchor node, coefficient)
    # per node
    live = np.flatnonzero(edges.coef != 0)
    node, anchor = sub.node_of_W[live], sub.node_of_W[edges.anchor_entry[live]]
    for n in np.unique(node):
        assert np.unique(anchor[node == n]).size == 1
        assert np.unique(edges.coef[live[node == n]]).size == 1
    assert live.size > 0 and np.unique(node).size < live.size      # shared nodes were checked


def test_weighted_transformed_matrices():
    sub = _sub(_random_weights)
    space = sub.primal_space()
    T = space.T_W.toarray()
    np.testing.assert_allclose(space.sub.K_W.toarray(), T.T @ sub.K_W.toarray() @ T, atol=1e-10)
    np.testing.assert_allclose(space.sub.f_W, T.T @ sub.f_W, atol=1e-13)


def test_edge_without_weight_falls_back_to_the_nodal_average():
    sub = _sub(np.zeros)
    plain = _sub()
    d = sub.primal_space().T_W - plain.primal_space().T_W
    assert d.count_nonzero() == 0


def test_wrong_number_of_weights():
    sub = _sub(lambda n: np.ones(n + 1))
    with pytest.raises(ValueError, match="primal"):
        sub.primal_space()


@pytest.mark.parametrize("method", sorted(SOLVERS))
def test_weighted_matches_direct(method):
    sub = _sub(_random_weights, ns=4, m=4)
    out = SOLVERS[method](sub, rtol=1e-10)
    assert out.krylov.converged
    ref = solve_direct(sub).u
    A = sub.global_matrix()
    e = out.u - ref
    assert np.sqrt(e @ A @ e) / np.sqrt(ref @ A @ ref) < 1e-8
