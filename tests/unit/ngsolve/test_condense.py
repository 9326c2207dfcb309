"""ddsolve.ngsolve.local.condense against the Schur complement written out, bubbles first, last or mixed."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ngsolve")
from ddsolve.ngsolve.local import condense


@pytest.mark.parametrize("n_w,n_b,shuffle", [(9, 1, False), (9, 1, True), (12, 3, False), (12, 3, True),
                                             (6, 0, False)])
def test_condense_is_the_schur_complement_of_the_bubbles(n_w, n_b, shuffle):
    rng = np.random.default_rng(n_w + n_b + shuffle)
    ne, n = 50, n_w + n_b
    A = rng.standard_normal((ne, n, n))
    Ke = A @ A.transpose(0, 2, 1) + n * np.eye(n)
    T = np.empty((ne, n), dtype=np.int64)
    T[:, :n_w] = rng.integers(0, 20, (ne, n_w))                # shared dofs
    T[:, n_w:] = 20 + np.arange(ne * n_b).reshape(ne, n_b)    # one element each: bubbles
    perm = rng.permutation(n) if shuffle else np.arange(n)
    T, Ke = T[:, perm], Ke[:, perm][:, :, perm]
    free = np.ones(20 + ne * n_b, dtype=bool)
    c = condense(Ke, T, free)
    bubble = perm >= n_w
    np.testing.assert_array_equal(c.b, np.flatnonzero(bubble))
    np.testing.assert_array_equal(c.w, np.flatnonzero(~bubble))
    w, b = c.w, c.b
    if n_b == 0:
        assert c.S is Ke and c.E is None
        return
    for e in (0, 17, ne - 1):
        K = Ke[e]
        Kbb_inv = np.linalg.inv(K[np.ix_(b, b)])
        S = K[np.ix_(w, w)] - K[np.ix_(w, b)] @ Kbb_inv @ K[np.ix_(b, w)]
        np.testing.assert_allclose(c.S[e], S, rtol=1e-12, atol=1e-12 * np.abs(S).max())
        np.testing.assert_allclose(c.Kbb_inv[e], Kbb_inv, rtol=1e-12)
        np.testing.assert_allclose(c.E[e], Kbb_inv @ K[np.ix_(b, w)], rtol=1e-11, atol=1e-13)
    fixed = free.copy()
    fixed[T[0, c.b[0]]] = False                                # a Dirichlet bubble is no bubble
    assert c.b[0] not in condense(Ke, T, fixed).b
