"""Sort-based helpers of ddsolve.scene.scene against numpy's own unique."""
import numpy as np
import pytest

from ddsolve.scene.scene import unique_row_labels


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("k", [1, 2, 3])
def test_unique_row_labels_equal_numpy_inverse(seed, k):
    rng = np.random.default_rng(seed)
    rows = rng.integers(0, 4, size=(500, k))                 # many repeated rows
    expected = np.unique(rows, axis=0, return_inverse=True)[1].ravel()
    np.testing.assert_array_equal(unique_row_labels(rows), expected)


def test_unique_row_labels_of_coordinates():
    """Rounded coordinates, -0.0 equal to 0.0 (as numpy's unique treats them), rows in any order."""
    rng = np.random.default_rng(7)
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 9), np.linspace(0, 1, 5)), axis=-1).reshape(-1, 2)
    rows = np.round(grid[rng.integers(0, grid.shape[0], size=300)], 9)
    rows[rows == 0.0] = -0.0
    rows[:10][rows[:10] == -0.0] = 0.0
    labels = unique_row_labels(rows)
    np.testing.assert_array_equal(labels, np.unique(rows, axis=0, return_inverse=True)[1].ravel())
    assert labels.max() + 1 == len({tuple(r) for r in (rows + 0.0).tolist()})


def test_unique_row_labels_of_no_rows():
    assert unique_row_labels(np.zeros((0, 2))).shape == (0,)
