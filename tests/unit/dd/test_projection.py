"""The one Projection class (dd/projection.py) and the scaled-jump operator B_D S B_D^T."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from ddsolve.dd.operators import PairJump, scaled_jump
from ddsolve.dd.projection import Projection


def coarse_space(seed: int, n: int = 12, k: int = 3) -> sp.csr_matrix:
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((n, k))
    G[rng.random((n, k)) < 0.4] = 0.0
    G[np.arange(k), np.arange(k)] = 1.0             # full column rank
    return sp.csr_matrix(G)


@pytest.mark.parametrize("sparse", [False, True])
def test_orthogonal_projection_2_13(sparse):
    """P = I - G (G^T G)^{-1} G^T: symmetric, idempotent, onto ker(G^T); lambda_0 satisfies G^T lambda_0 = e."""
    G = coarse_space(0)
    P = Projection(G, sparse=sparse)
    Pd = np.column_stack([P.apply(e) for e in np.eye(P.n)])
    Gd = G.toarray()
    ref = np.eye(P.n) - Gd @ np.linalg.solve(Gd.T @ Gd, Gd.T)
    np.testing.assert_allclose(Pd, ref, atol=1e-13)
    np.testing.assert_allclose(Pd, Pd.T, atol=1e-13)
    e = np.array([1.0, -2.0, 0.5])
    np.testing.assert_allclose(Gd.T @ P.particular(e), e, atol=1e-12)
    r = np.random.default_rng(1).standard_normal(P.n)
    np.testing.assert_allclose(P.coefficients(r), np.linalg.lstsq(Gd, r, rcond=None)[0], atol=1e-12)
    op = P.as_operator()
    np.testing.assert_allclose(op.matvec(r), P.apply(r), atol=0)


def test_weighted_projection_diagonal_and_callable():
    """Q-weighted P = I - Q G (G^T Q G)^{-1} G^T: range ker(G^T), P^T kills range(G); diagonal Q = callable Q."""
    G = coarse_space(2)
    q = np.random.default_rng(3).uniform(0.5, 4.0, G.shape[0])
    Pq = Projection(G, q, singular_tol=1e-12)
    Pc = Projection(G, lambda g: q * g, singular_tol=1e-12)
    Gd = G.toarray()
    for v in np.eye(G.shape[0]):
        np.testing.assert_allclose(Pq.apply(v), Pc.apply(v), atol=1e-13)
        assert np.abs(Gd.T @ Pq.apply(v)).max() < 1e-12
        np.testing.assert_allclose(Pq.apply(Pq.apply(v)), Pq.apply(v), atol=1e-12)
    assert np.abs(np.column_stack([Pq.apply_transpose(g) for g in Gd.T])).max() < 1e-12


def test_orthonormal_row_and_singular_coarse_problem():
    g = np.array([0.0, 0.0, -1.0, -1.0]) / np.sqrt(2.0)       # one row of (6.17), ||g|| = 1
    P = Projection(g, orthonormal=True)
    v = np.array([1.0, 2.0, 3.0, 5.0])
    np.testing.assert_allclose(P.apply(v), v - g * (g @ v), atol=0)
    np.testing.assert_allclose(P.complement(v) + P.apply(v), v, atol=1e-15)
    with pytest.raises(ValueError, match="tied"):
        Projection(sp.csr_matrix(np.zeros((4, 1))), singular_tol=1e-10, singular_message="not tied")
    empty = Projection(sp.csr_matrix((4, 0)))
    assert empty.apply(v) is v and empty.k == 0


def test_scaled_jump_pairs_equal_sparse():
    """B_D S B_D^T by index pairs equals the sparse-matrix form."""
    rng = np.random.default_rng(4)
    n, m = 9, 5
    first, second = rng.choice(n, m, replace=False), rng.choice(n, m, replace=False)
    c1, c2 = rng.uniform(0.1, 1, m), rng.uniform(0.1, 1, m)
    B_D = sp.csr_matrix((np.r_[c1, -c2], (np.r_[np.arange(m), np.arange(m)], np.r_[first, second])), shape=(m, n))
    S = rng.standard_normal((n, n))
    S = S @ S.T
    lam = rng.standard_normal(m)
    pairs = PairJump(first, second, n, c1, c2)
    np.testing.assert_allclose(scaled_jump(pairs, lambda v: S @ v)(lam), scaled_jump(B_D, lambda v: S @ v)(lam),
                               atol=1e-12)
    np.testing.assert_allclose(PairJump(first, second, n).rmatvec(lam),
                               np.bincount(first, lam, n) - np.bincount(second, lam, n), atol=0)
