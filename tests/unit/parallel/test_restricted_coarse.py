"""RestrictedCoarse: a rank factors only the blocks of a block-diagonal coarse matrix it reads."""
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddsolve.parallel.coarse import RestrictedCoarse


def _spd_block(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, n))
    return X @ X.T + n * np.eye(n)


def _three_blocks():
    """Three independent SPD blocks, their dofs interleaved, plus one pinned dof (an identity row)."""
    blocks = [_spd_block(5, 1), _spd_block(7, 2), _spd_block(4, 3)]
    n = 17
    order = np.random.default_rng(4).permutation(n)
    groups = [order[:5], order[5:12], order[12:16], order[16:]]
    A = np.zeros((n, n))
    for g, B in zip(groups, blocks):
        A[np.ix_(g, g)] = B
    A[groups[3], groups[3]] = 1.0
    return sp.csc_matrix(A), groups


def test_solves_the_touched_blocks_only():
    S, groups = _three_blocks()
    b = np.random.default_rng(5).standard_normal(S.shape[0])
    full = spla.spsolve(S, b)
    touched = np.zeros(S.shape[0], dtype=bool)
    touched[groups[0][:2]] = True               # one dof of a block brings the whole block
    touched[groups[2][-1]] = True
    factor = RestrictedCoarse.of(S, touched)
    assert isinstance(factor, RestrictedCoarse)
    kept = np.sort(np.concatenate([groups[0], groups[2]]))
    np.testing.assert_array_equal(factor.index, kept)
    x = factor.solve(b)
    np.testing.assert_allclose(x[kept], full[kept], rtol=1e-12)
    dropped = np.setdiff1d(np.arange(S.shape[0]), kept)
    assert np.all(x[dropped] == 0.0)


def test_every_block_touched_is_the_plain_factor():
    S, groups = _three_blocks()
    touched = np.zeros(S.shape[0], dtype=bool)
    for g in groups:
        touched[g[0]] = True
    factor = RestrictedCoarse.of(S, touched)
    assert not isinstance(factor, RestrictedCoarse)
    b = np.arange(S.shape[0], dtype=float)
    np.testing.assert_allclose(factor.solve(b), spla.spsolve(S, b), rtol=1e-12)


def test_one_connected_matrix_is_never_restricted():
    S = sp.csc_matrix(_spd_block(9, 6))
    touched = np.zeros(9, dtype=bool)
    touched[3] = True
    assert not isinstance(RestrictedCoarse.of(S, touched), RestrictedCoarse)
