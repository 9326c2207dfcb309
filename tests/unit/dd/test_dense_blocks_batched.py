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


def test_the_coarse_coupling_by_sparse_psi_rows_is_the_blocks_one(monkeypatch):
    """With more than GROUPS_LOOP_MAX groups the interface solve couples the coarse problem through the sparse
    rows of Psi instead of one dense Psi block per group: the same A~^-1 on the interface (64 METIS parts)."""
    import ddsolve.dd.primal as primal
    from ddsolve import ProblemSpec, prepare
    from ddsolve.dd.primal import ExplicitInterfaceSolve, PrimalConstrainedSolver

    sub = prepare(ProblemSpec(method="bddc", mesh="unstructured", geometry="square", maxh=0.08, parts=64)).sub
    solver = PrimalConstrainedSolver(sub, sub.vertex, {})
    b = np.where(sub.interface, np.random.default_rng(3).standard_normal(sub.n_W), 0.0)
    fast = ExplicitInterfaceSolve(solver, sub.interface)
    assert fast.blocks.coarse is None and fast.blocks.psi is not None and fast.blocks.blocks._batched is not None
    monkeypatch.setattr(primal, "GROUPS_LOOP_MAX", 10**9)
    looped = ExplicitInterfaceSolve(solver, sub.interface)
    assert looped.blocks.coarse is not None and len(looped.blocks.coarse) > GROUPS_LOOP_MAX
    x, y = fast.solve(b), looped.solve(b)
    np.testing.assert_allclose(x, y, rtol=0, atol=1e-11 * np.abs(y).max())


def test_positions_of_many_members_are_the_position_of_each():
    """Substructures.positions (one search for a whole group) replaced a call of position per member, a Python
    loop over the subdomains when the explicit local Schur blocks are formed (a review)."""
    from ddsolve import ProblemSpec, prepare

    for spec in (dict(method="feti", subdomains=4, elements=4),
                 dict(problem="multibody", bodies=2, subdomains=2, elements=3),
                 dict(method="bddc", mesh="unstructured", geometry="square", maxh=0.1, parts=8)):
        sub = prepare(ProblemSpec(**spec)).sub
        members = np.arange(sub.n_sub)[::-1]
        loc = sub._free_local[0][::2]
        same = [s for s in members if np.isin(loc, sub._free_local[s]).all()]
        got = sub.positions(np.asarray(same), loc)
        assert got.shape == (loc.size, len(same))
        for j, s in enumerate(same):
            np.testing.assert_array_equal(got[:, j], sub.position(s, loc))
