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
