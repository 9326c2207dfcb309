"""FloatingSums: R_c^T u and u - R_c m.

What must hold bitwise: the sums of one floating body do not depend on where its
entries lie in the vector (a serial u_Gamma, or a rank's local one holding the
whole body among other entries), so serial and distributed runs take the same
steps. Their accuracy is checked against an exact sum (``math.fsum``)."""
import math

import numpy as np
import pytest

from ddsolve.multibody.kernel import FloatingSums


def _reference(column, n_float, u, summed=None):
    on = column >= 0
    pick = on if summed is None else on & summed
    sums = np.bincount(column[pick], weights=u[pick], minlength=n_float)
    return sums


@pytest.mark.parametrize("layout", ["contiguous", "scattered", "two_bodies", "owned_subset"])
def test_sums_and_subtract(layout):
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
    if n_float > 1:
        assert np.array_equal(sums, ref)                              # the serial bits (bincount), bitwise
    for k in range(n_float):                                          # and accurate: against exact sums
        members = (column == k) if summed is None else (column == k) & summed
        assert abs(sums[k] - math.fsum(u[members])) <= 1e-14 * np.abs(u).sum()
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


def _wide(n, seed):
    rng = np.random.default_rng(seed)
    return rng.standard_normal(n) * 10.0 ** rng.integers(-8, 8, n)   # wide range: order of summation matters


@pytest.mark.parametrize("n", [1, 7, 129, 8191, 100_000])
def test_one_body_sum_independent_of_its_place(n):
    """The same entries alone (serial), at an offset, interleaved with others, or as a rank's owned
    subset: the same bits. A change to the summation rule that breaks this breaks P = 1 / P = 2 equality."""
    u = _wide(n, 11)
    serial = FloatingSums(np.zeros(n, dtype=np.int64), 1).sums(u)
    rng = np.random.default_rng(12)
    m = 3 * n + 5
    where = np.sort(rng.choice(m, n, replace=False))                   # scattered among other entries
    big = _wide(m, 13)
    big[where] = u
    column = np.full(m, -1)
    column[where] = 0
    assert np.array_equal(FloatingSums(column, 1).sums(big), serial)
    offset = np.full(m, -1)
    offset[n + 2:2 * n + 2] = 0                                         # one contiguous range at an offset
    shifted = _wide(m, 14)
    shifted[n + 2:2 * n + 2] = u
    assert np.array_equal(FloatingSums(offset, 1).sums(shifted), serial)
    owned = rng.random(m) < 0.5                                         # the rank owns the body's entries
    owned[where] = True
    assert np.array_equal(FloatingSums(column, 1, summed=owned).sums(big), serial)
    assert abs(serial[0] - math.fsum(u)) <= 1e-15 * math.fsum(np.abs(u)) * max(1, math.log2(n))
