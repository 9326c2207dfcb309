"""FloatingSums: R_c^T u and u - R_c m, bitwise equal to the bincount form it replaces."""
import numpy as np
import pytest

from ddsolve.multibody.kernel import FloatingSums


def _reference(column, n_float, u, summed=None):
    on = column >= 0
    pick = on if summed is None else on & summed
    sums = np.bincount(column[pick], weights=u[pick], minlength=n_float)
    return sums


@pytest.mark.parametrize("layout", ["contiguous", "scattered", "two_bodies", "owned_subset"])
def test_sums_and_subtract_bitwise_equal_to_bincount(layout):
    rng = np.random.default_rng(7)
    n = 5000
    u = rng.standard_normal(n) * 10.0 ** rng.integers(-8, 8, n)      # wide range: order of summation matters
    column = np.full(n, -1)
    summed = None
    n_float = 1
    if layout == "contiguous":
        column[1200:4100] = 0
    elif layout == "scattered":
        column[rng.random(n) < 0.4] = 0
    elif layout == "two_bodies":
        column[1000:2500] = 0
        column[3000:4500] = 1
        n_float = 2
    else:
        column[2000:] = 0
        summed = rng.random(n) < 0.7
    fs = FloatingSums(column, n_float, summed=summed)
    sums = fs.sums(u)
    ref = _reference(column, n_float, u, summed)
    assert sums.shape == (n_float,)
    assert np.array_equal(sums, ref)                                  # bitwise, not approximately
    on = column >= 0
    assert np.array_equal(fs.counts, np.bincount(column[on if summed is None else on & summed],
                                                 minlength=n_float))
    m = np.array([0.25, -3.5])[:n_float]
    out = fs.subtract(u, m)
    expect = u.copy()
    expect[column >= 0] -= m[column[column >= 0]]
    assert np.array_equal(out, expect)
    assert out is not u


def test_no_summed_entries_gives_zero():
    column = np.array([-1, 0, 0, -1])
    fs = FloatingSums(column, 1, summed=np.zeros(4, dtype=bool))
    assert np.array_equal(fs.sums(np.arange(4.0)), [0.0])
    assert np.array_equal(fs.subtract(np.arange(4.0), np.array([1.0])), [0.0, 0.0, 1.0, 3.0])


def test_pairwise_sum_would_differ():
    """The reason for cumsum: np.sum (pairwise) is not the bincount order, so it can change the last bits."""
    rng = np.random.default_rng(3)
    u = rng.standard_normal(100_000) * 10.0 ** rng.integers(-8, 8, 100_000)
    column = np.zeros(u.size, dtype=np.int64)
    assert np.bincount(column, weights=u)[0] != np.sum(u)
    assert FloatingSums(column, 1).sums(u)[0] == np.bincount(column, weights=u)[0]
