"""DenseBlocks with many one-member groups (a general mesh): one sparse block-diagonal product, no loop."""
from __future__ import annotations

import numpy as np

from ddsolve.dd.local import GROUPS_LOOP_MAX, DenseBlocks


def _blocks(n_single: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    blocks, at = [], 0
    for k in range(n_single + 2):
        n = int(rng.integers(2, 12))
        members = 3 if k in (5, n_single) else 1             # two shared groups among the single ones
        A = rng.standard_normal((n, n))
        index = np.arange(at, at + n * members).reshape(n, members)
        at += n * members
        blocks.append((A, index, rng.uniform(0.5, 2.0, members)))
    return blocks


def _reference(blocks, xs):
    out, off = [], 0
    for A, index, scale in blocks:
        n, m = index.shape
        out.append(((A @ xs[off:off + n * m].reshape(n, m)) * scale).ravel())
        off += n * m
    return np.concatenate(out)


def test_many_one_member_groups_are_one_sparse_product():
    """More than GROUPS_LOOP_MAX groups: the one-member ones are batched (a review: one GEMV per subdomain and
    application cost 7.7 ms at 4,096 parts), the shared ones keep their GEMM; the product is the blocks' own."""
    blocks = _blocks(GROUPS_LOOP_MAX + 8)
    dense = DenseBlocks(blocks)
    assert dense._batched is not None and len(dense._looped) == 2
    xs = np.random.default_rng(1).standard_normal(dense.size)
    np.testing.assert_allclose(dense.apply(xs), _reference(blocks, xs), rtol=1e-13, atol=1e-13)


def test_few_groups_keep_their_gemms():
    blocks = _blocks(10)
    dense = DenseBlocks(blocks)
    assert dense._batched is None and len(dense._looped) == len(blocks)
    xs = np.random.default_rng(2).standard_normal(dense.size)
    np.testing.assert_array_equal(dense.apply(xs), _reference(blocks, xs))
