"""Scenes, NGSolve assembly, template sharing and interface classification."""
import numpy as np
import pytest

from ddsolve.errors import InputError
from ddsolve.scene import assemble, checkerboard, structured_square

from conftest import substructures


def test_structured_counts():
    sc = structured_square(1, 3, 4)
    n = 12
    assert sc.n_nodes == (n + 1) ** 2
    assert sc.elements.shape == (n * n, 4)
    assert sc.n_subdomains == 9
    assert sc.dirichlet.sum() == 4 * n
    assert np.bincount(sc.element_subdomain).tolist() == [16] * 9


def test_multibody_nodes_are_duplicated_and_paired():
    sc = structured_square(2, 2, 2)
    n = 4
    assert sc.n_nodes == 4 * (n + 1) ** 2
    # 4 faces between bodies, n+1 matching nodes each
    assert sc.contact_pairs.shape == (4 * (n + 1), 2)
    a, b = sc.contact_pairs.T
    np.testing.assert_allclose(sc.coords[a], sc.coords[b])
    assert np.all(sc.subdomain_body[sc.element_subdomain[0]] == 0)


def test_assembled_q1_stiffness_and_load():
    local = assemble(structured_square(1, 2, 4, f=2.0))
    assert local.n_templates == 1
    K = local.stiffness[0].toarray()
    np.testing.assert_allclose(K, K.T, atol=1e-14)
    np.testing.assert_allclose(K.sum(axis=1), 0.0, atol=1e-13)          # Neumann matrix: constants in kernel
    assert K[0, 0] == pytest.approx(2 / 3)                                 # Q1 corner
    centre = 2 * 5 + 2
    assert K[centre, centre] == pytest.approx(8 / 3)                       # Q1 interior stencil
    assert np.sort(K[centre])[:8] == pytest.approx([-1 / 3] * 8)
    total = sum(l.sum() for l in local.loads)
    assert total == pytest.approx(2.0)                                     # int_Omega f = 2


def test_global_matrix_is_the_q1_laplacian():
    sub = substructures(subdomains=2, elements=3)
    A = sub.global_matrix().toarray()
    n = 5                                                                  # interior nodes per side
    assert A.shape == (n * n, n * n)
    centre = 2 * n + 2
    assert A[centre, centre] == pytest.approx(8 / 3)
    assert np.count_nonzero(np.abs(A[centre]) > 1e-14) == 9


def test_random_load_is_seeded():
    a = substructures(subdomains=2, elements=4, f="random:3").f_W
    b = substructures(subdomains=2, elements=4, f="random:3").f_W
    c = substructures(subdomains=2, elements=4, f="random:4").f_W
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-3


def test_interface_classification():
    sub = substructures(subdomains=3, elements=4)
    # cross points of the 3x3 decomposition: 4 vertices, each shared by 4 subdomains
    vertex_nodes = np.unique(sub.node_of_W[sub.vertex])
    assert vertex_nodes.size == 4
    assert np.all(sub.multiplicity[sub.vertex] == 4)
    # edges: 12 interface edges of 3 interior nodes each
    edge_nodes = np.unique(sub.node_of_W[sub.interface & ~sub.vertex])
    assert edge_nodes.size == 12 * 3
    assert sub.floating_sub.sum() == 1                                     # the centre subdomain floats


def test_rho_scaling_weights_sum_to_one():
    sub = substructures(subdomains=3, elements=2, rho="checkerboard:10")
    sums = np.bincount(sub.node_of_W, weights=sub.delta)
    np.testing.assert_allclose(sums[np.unique(sub.node_of_W)], 1.0)
    on_edge = sub.interface & ~sub.vertex
    heavy = sub.rho[sub.sub_of_W] == 10.0
    np.testing.assert_allclose(sub.delta[on_edge & heavy], 10 / 11)


def test_checkerboard_pattern():
    grid = np.array([[0, 0], [1, 0], [0, 1], [1, 1]])
    assert checkerboard(grid, 5.0).tolist() == [1.0, 5.0, 5.0, 1.0]


def test_scene_rejects_bad_rho():
    with pytest.raises(InputError, match="rho"):
        structured_square(1, 2, 2, rho=-1.0)
