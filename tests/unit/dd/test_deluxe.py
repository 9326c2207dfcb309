"""ddsolve.dd.deluxe on hand-made blocks: two subdomains sharing one local Schur complement (one group
of two members, as structured templates give) with different coefficients, and a third entry kept diagonal."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ddsolve.dd.deluxe import deluxe_scaling
from ddsolve.dd.local import DenseBlocks


def test_face_blocks_from_a_shared_template_with_member_scales():
    rng = np.random.default_rng(11)
    G = rng.standard_normal((3, 3))
    S = G @ G.T + 3 * np.eye(3)                     # the template's interface Schur complement
    # W: subdomain 0 entries 0,1,2 (nodes 10, 11, 12), subdomain 1 entries 3,4,5 (nodes 12, 11, 10)
    index = np.array([[0, 3], [1, 4], [2, 5]])      # local row k of member m -> W position
    rho = np.array([2.0, 50.0])
    blocks = DenseBlocks([(S, index, rho)])
    sub = SimpleNamespace(n_W=6, n_sub=2, sub_of_W=np.array([0, 0, 0, 1, 1, 1]),
                          node_of_W=np.array([10, 11, 12, 12, 11, 10]))
    dual = np.array([True, True, False, False, True, True])     # node 12 is primal
    delta = np.full(6, 0.5)
    dlx = deluxe_scaling(sub, blocks, dual, delta)
    assert dlx.n_faces == 1 and dlx.largest_face == 2
    D = dlx.D.toarray()
    # face nodes (10, 11): subdomain 0 rows (0, 1) of S, subdomain 1 rows (2, 1) of S (its entries 5, 4)
    S0 = rho[0] * S[np.ix_([0, 1], [0, 1])]
    S1 = rho[1] * S[np.ix_([2, 1], [2, 1])]
    D0 = np.linalg.solve(S0 + S1, S0)
    np.testing.assert_allclose(D[np.ix_([0, 1], [0, 1])], D0, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(D[np.ix_([5, 4], [5, 4])], np.eye(2) - D0, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(np.diag(D)[[2, 3]], [0.5, 0.5])             # off the face: delta
    assert dlx.face_entries.tolist() == [True, True, False, False, True, True]
    assert np.count_nonzero(D) == 2 * 4 + 2


def test_a_glob_of_three_copies_and_its_fetidp_rows():
    """Nodes 20, 21 shared by three subdomains (a dual 3D edge under edge averages): D_i =
    (S_0 + S_1 + S_2)^{-1} S_i, sum_i D_i = I, and the FETI-DP rows B_D = (1/3) B (I - E_D^T) of the
    fully redundant multipliers give P_D = B_D^T B = I - E_D."""
    import scipy.sparse as sp

    rng = np.random.default_rng(5)
    Ss = []
    for _ in range(3):
        G = rng.standard_normal((2, 2))
        Ss.append(G @ G.T + 2 * np.eye(2))
    # subdomain s holds W entries 2s (node 20) and 2s+1 (node 21)
    blocks = DenseBlocks([(Ss[s], np.array([[2 * s], [2 * s + 1]]), np.array([1.0 + 10 * s])) for s in range(3)])
    sub = SimpleNamespace(n_W=6, n_sub=3, sub_of_W=np.repeat(np.arange(3), 2), node_of_W=np.tile([20, 21], 3))
    dual = np.ones(6, dtype=bool)
    dlx = deluxe_scaling(sub, blocks, dual, np.full(6, 1 / 3))
    assert dlx.n_faces == 1 and dlx.largest_face == 2 and dlx.copies.tolist() == [3] * 6
    D = dlx.D.toarray()
    scaled = [(1.0 + 10 * s) * Ss[s] for s in range(3)]
    total = sum(scaled)
    blocks_D = [D[2 * s:2 * s + 2, 2 * s:2 * s + 2] for s in range(3)]
    for s in range(3):
        np.testing.assert_allclose(blocks_D[s], np.linalg.solve(total, scaled[s]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(sum(blocks_D), np.eye(2), atol=1e-14)
    # fully redundant multipliers: one row per pair of copies of each node
    rows = [(a, b) for node in (0, 1) for a, b in ((0, 1), (0, 2), (1, 2))]
    B = np.zeros((6, 6))
    for r, (node, (a, b)) in enumerate(zip([0, 0, 0, 1, 1, 1], rows[:3] + rows[:3])):
        B[r, 2 * a + node], B[r, 2 * b + node] = 1.0, -1.0
    R = sp.csr_matrix(np.tile(np.eye(2), (3, 1)))          # W copies of the two assembled dofs
    B_D = dlx.jump(sp.csr_matrix(B), sp.csr_matrix(B / 3), R).toarray()
    E_D = R.toarray() @ R.toarray().T @ D
    np.testing.assert_allclose(B_D.T @ B, np.eye(6) - E_D, atol=1e-13)
