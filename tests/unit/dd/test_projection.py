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


def _body_graph_G(n_side: int, tied_cols=(0,), seed: int = 3) -> sp.csr_matrix:
    """G = B R of a grid of floating bodies: two-entry rows (+1, -1) between neighbours (2 rows each), and a
    one-entry row (a tie to a clamped body) for each column of ``tied_cols``; rows shuffled."""
    k = n_side * n_side
    rows = []
    for i in range(n_side):
        for j in range(n_side):
            c = i * n_side + j
            for d in ((0, 1), (1, 0)):
                if i + d[0] < n_side and j + d[1] < n_side:
                    rows += [{c: 1.0, (i + d[0]) * n_side + j + d[1]: -1.0}] * 2
    rows += [{c: (-1.0) ** c} for c in tied_cols]
    order = np.random.default_rng(seed).permutation(len(rows))
    r = [rows[o] for o in order]
    return sp.csr_matrix((np.concatenate([list(x.values()) for x in r]),
                          (np.repeat(np.arange(len(r)), [len(x) for x in r]),
                           np.concatenate([list(x.keys()) for x in r]))), shape=(len(r), k))


def test_kernel_is_trivial_reads_the_body_graph():
    from ddsolve.dd.projection import gram_is_singular, kernel_is_trivial

    G = _body_graph_G(6)
    assert kernel_is_trivial(G) is True and not gram_is_singular(G, 1e-10)
    untied = _body_graph_G(6, tied_cols=())
    assert kernel_is_trivial(untied) is False and gram_is_singular(untied, 1e-10)
    two = sp.vstack([G, sp.csr_matrix(([1.0, 1.0], ([0, 0], [0, 1])), shape=(1, 36))]).tocsr()
    assert kernel_is_trivial(two) is None                   # equal signs: not a tie, the structure says nothing
    weighted = sp.vstack([G, sp.csr_matrix(([2.0, -1.0], ([0, 0], [0, 1])), shape=(1, 36))]).tocsr()
    assert kernel_is_trivial(weighted) is None              # unequal sizes: likewise


def test_many_columns_are_factored_sparse_with_the_same_projection(monkeypatch):
    """Beyond DENSE_COARSE_MAX columns the orthogonal projection is checked from G's structure and factored by
    sparse LU (a review: 3,844 floating bodies made a 1.5 GB dense copy of G and O(k^3) eigensolves); P is the
    dense path's to rounding, and an untied body is refused the same way."""
    import ddsolve.dd.projection as projection

    G = _body_graph_G(12)                                          # k = 144
    v = np.random.default_rng(5).standard_normal(G.shape[0])
    dense = Projection(G, singular_tol=1e-10, singular_message="untied")
    monkeypatch.setattr(projection, "DENSE_COARSE_MAX", 50)
    fast = Projection(G, singular_tol=1e-10, singular_message="untied")
    assert fast._factor[0] == "splu" and dense._factor[0] == "cho"
    np.testing.assert_allclose(fast.apply(v), dense.apply(v), rtol=0, atol=1e-12 * np.abs(v).max())
    assert np.abs(G.T @ fast.apply(v)).max() < 1e-10
    with pytest.raises(ValueError, match="^untied$"):
        Projection(_body_graph_G(12, tied_cols=()), singular_tol=1e-10, singular_message="untied")
