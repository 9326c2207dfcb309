"""The MKL PARDISO backend of the batched block-diagonal factorization against SuperLU."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddsolve.dd import Substructures, local, pardiso
from ddsolve.dd.bddc import solve_bddc
from ddsolve.dd.fetidp import solve_fetidp
from ddsolve.scene import assemble
from ddsolve.scene.unstructured import unstructured_scene

needs_mkl = pytest.mark.skipif(not pardiso.available(), reason="MKL PARDISO needs the mkl wheel (pip install mkl)")


def _laplacian(m: int, shift: float) -> sp.csr_matrix:
    """5-point Laplacian of an m x m grid plus shift * I (SPD)."""
    T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    return sp.csr_matrix(sp.kron(sp.eye(m), T) + sp.kron(T, sp.eye(m)) + shift * sp.eye(m * m))


@needs_mkl
def test_pardiso_cholesky_solves_like_superlu():
    K = sp.block_diag([_laplacian(30, 0.0), _laplacian(25, 1e-3), _laplacian(40, 1.0)], format="csr")
    rng = np.random.default_rng(11)
    B = rng.standard_normal((K.shape[0], 5))
    ref = spla.splu(sp.csc_matrix(K)).solve(B)
    f = pardiso.PardisoCholesky(K)
    for X, R in ((f.solve(B[:, 0]), ref[:, 0]), (f.solve(B), ref)):
        assert X.shape == R.shape
        assert np.linalg.norm(X - R) <= 1e-12 * np.linalg.norm(R)
    assert f.solve(np.zeros((K.shape[0], 0))).shape == (K.shape[0], 0)


@needs_mkl
def test_pardiso_rejects_an_indefinite_matrix():
    K = _laplacian(40, -0.5)            # eigenvalues below 0.5 turn negative
    with pytest.raises(RuntimeError, match="PARDISO"):
        pardiso.PardisoCholesky(K)


def _sub():
    sc = unstructured_scene("poisson", geometry="hole", maxh=0.015, parts=24,
                            rho=10.0 ** np.random.default_rng(5).integers(-2, 3, size=24))
    return Substructures(assemble(sc))


def _batched(sub, backend, monkeypatch):
    monkeypatch.setattr(local, "SPARSE_BACKEND", backend)
    return local.BatchedSolver(sub, ~sub.interface, {})


@needs_mkl
def test_batched_pardiso_equals_superlu(monkeypatch):
    sub = _sub()
    a, b = _batched(sub, "superlu", monkeypatch), _batched(sub, "pardiso", monkeypatch)
    assert a._batch[0].backend == "superlu" and b._batch[0].backend == "pardiso"
    assert b._batch[1].size > local.DENSE_LIMIT
    rng = np.random.default_rng(2)
    for rhs in (rng.standard_normal(sub.n_W), rng.standard_normal((sub.n_W, 4))):
        xa, xb = a.solve(rhs), b.solve(rhs)
        assert np.linalg.norm(xb - xa) <= 1e-12 * np.linalg.norm(xa)
    # one block alone and the multi-column setup solves
    g = b.groups[3]
    B = rng.standard_normal((g.index.shape[0], 3))
    ya, yb = a.groups[3].factor.solve(B), g.factor.solve(B)
    assert np.linalg.norm(yb - ya) <= 1e-12 * np.linalg.norm(ya)
    tasks = [(gr.factor, rng.standard_normal((gr.index.shape[0], 1 + k % 3))) for k, gr in enumerate(b.groups)]
    ref = local.solve_many([(ga.factor, B) for ga, (_, B) in zip(a.groups, tasks)])
    for Xb, Xa in zip(local.solve_many(tasks), ref):
        assert np.linalg.norm(Xb - Xa) <= 1e-12 * np.linalg.norm(Xa)


@needs_mkl
@pytest.mark.parametrize("method", [solve_fetidp, solve_bddc])
def test_methods_with_pardiso_match_superlu(method, monkeypatch):
    sub = _sub()
    monkeypatch.setattr(local, "SPARSE_BACKEND", "superlu")
    a = method(sub, rtol=1e-10)
    monkeypatch.setattr(local, "SPARSE_BACKEND", "pardiso")
    b = method(sub, rtol=1e-10)
    assert abs(a.krylov.iterations - b.krylov.iterations) <= 1
    assert np.linalg.norm(b.u - a.u) <= 1e-9 * np.linalg.norm(a.u)


def test_backend_choice(monkeypatch):
    K = sp.csc_matrix(_laplacian(40, 0.0))
    monkeypatch.setattr(local, "SPARSE_BACKEND", "superlu")
    assert local._sparse_backend(K) == "superlu"
    monkeypatch.setattr(local, "SPARSE_BACKEND", "auto")
    assert local._sparse_backend(K) == ("pardiso" if pardiso.available() else "superlu")
    monkeypatch.setattr(local, "SPARSE_BACKEND", "umfpack")
    with pytest.raises(ValueError, match="SPARSE_BACKEND"):
        local._sparse_backend(K)
    # factorizations of one subdomain's template stay SuperLU (structured scenes, the tables)
    monkeypatch.setattr(local, "SPARSE_BACKEND", "auto")
    assert local._Factor(K).backend == "superlu"


def test_subdomain_ordering_is_a_permutation_within_each_subdomain():
    pytest.importorskip("pymetis")
    sub = _sub()
    order = local._subdomain_ordering(sub, {})
    offsets = np.asarray(sub.offsets)
    block = np.searchsorted(offsets, np.arange(sub.n_W), side="right") - 1
    np.testing.assert_array_equal(np.sort(order), np.arange(sub.n_W))
    np.testing.assert_array_equal(block[order], block)             # subdomain after subdomain
    entries = np.flatnonzero(~sub.interface)
    restricted = local._restricted_order(order, entries, sub.n_W)
    np.testing.assert_array_equal(np.sort(restricted), np.arange(entries.size))
    np.testing.assert_array_equal(entries[restricted], order[np.isin(order, entries)])


@needs_mkl
def test_subdomain_ordering_and_pardiso_ordering_agree(monkeypatch):
    sub = _sub()
    monkeypatch.setattr(local, "BATCH_ORDERING", "subdomain")
    a = _batched(sub, "pardiso", monkeypatch)
    assert a._batch[0]._f._iparm[4] == 1                          # the user ordering was handed over
    monkeypatch.setattr(local, "BATCH_ORDERING", "pardiso")
    b = _batched(sub, "pardiso", monkeypatch)
    assert b._batch[0]._f._iparm[4] == 0
    rhs = np.random.default_rng(8).standard_normal((sub.n_W, 2))
    xa, xb = a.solve(rhs), b.solve(rhs)
    assert np.linalg.norm(xb - xa) <= 1e-12 * np.linalg.norm(xa)


@needs_mkl
def test_coarse_factor_backend_by_stored_entries(monkeypatch):
    """ddsolve.dd.coarse.coarse_factor: PARDISO from COARSE_PARDISO_MIN_NNZ entries, SuperLU below and
    for a matrix PARDISO finds not positive definite; each solves like a direct solve."""
    from ddsolve.dd import coarse

    K = _laplacian(20, 1e-2)
    rng = np.random.default_rng(5)
    b = rng.standard_normal(K.shape[0])
    ref = spla.spsolve(sp.csc_matrix(K), b)
    monkeypatch.setattr(coarse, "COARSE_PARDISO_MIN_NNZ", K.nnz)
    dense_coupling = coarse.coarse_factor(K)
    assert isinstance(dense_coupling, pardiso.PardisoCholesky)
    np.testing.assert_allclose(dense_coupling.solve(b), ref, rtol=1e-10)
    monkeypatch.setattr(coarse, "COARSE_PARDISO_MIN_NNZ", K.nnz + 1)
    sparse = coarse.coarse_factor(K)
    assert not isinstance(sparse, pardiso.PardisoCholesky)
    np.testing.assert_allclose(sparse.solve(b), ref, rtol=1e-10)
    monkeypatch.setattr(coarse, "COARSE_PARDISO_MIN_NNZ", 1)
    indefinite = sp.csr_matrix(K - 2.0 * sp.eye(K.shape[0]))
    fallback = coarse.coarse_factor(indefinite)
    assert not isinstance(fallback, pardiso.PardisoCholesky)
    np.testing.assert_allclose(indefinite @ fallback.solve(b), b, rtol=1e-8, atol=1e-10)


def test_anchored_order_on_a_synthetic_layout():
    """local._anchored_order: the self-anchored entries in the nested dissection of their own graph,
    every other entry just before its first anchor, blocks (one of them empty) kept in order."""
    pytest.importorskip("pymetis")
    G = sp.block_diag([_laplacian(6, 0.0), _laplacian(5, 0.0)], format="csr")
    offsets = np.array([0, 36, 36, 61])                      # block 1 is empty
    n = G.shape[0]
    anchors = np.full((n, 2), -1, dtype=np.int64)
    own = np.zeros(n, dtype=bool)
    own[0:36:2] = own[36:61:3] = True
    anchors[own, 0] = np.flatnonzero(own)
    for w in np.flatnonzero(~own):                           # the next own entries of the same block
        hi = 36 if w < 36 else 61
        later = np.flatnonzero(own[w:hi]) + w
        anchors[w, :later[:2].size] = later[:2]
    anchors[60] = -1                                         # no anchor: ordered as its own
    order = local._anchored_order(G, offsets, anchors)
    np.testing.assert_array_equal(np.sort(order), np.arange(n))
    np.testing.assert_array_equal(order < 36, np.arange(n) < 36)        # block 0 first
    selfs = np.flatnonzero(own | (anchors.max(axis=1) < 0))
    sub_offsets = np.array([0, np.count_nonzero(selfs < 36), np.count_nonzero(selfs < 36), selfs.size])
    expected = selfs[local._nested_dissection(G[selfs][:, selfs].tocsr(), sub_offsets)]
    np.testing.assert_array_equal(order[np.isin(order, selfs)], expected)
    position = np.empty(n, dtype=np.int64)
    position[order] = np.arange(n)
    for w in np.flatnonzero(~own & (anchors.max(axis=1) >= 0)):
        first = min(position[a] for a in anchors[w] if a >= 0)
        assert position[w] < first
        assert not np.isin(order[position[w]:first], selfs).any()     # no own entry in between


def test_upper_triangle_arrays_match_scipy_triu():
    """pardiso._upper_triangle: the CSR arrays of triu(K) with sorted rows, also from unsorted CSR or CSC input."""
    rng = np.random.default_rng(3)
    A = sp.random(60, 60, density=0.1, random_state=rng, format="csr")
    K = sp.csr_matrix(A + A.T + 60 * sp.eye(60))
    shuffled = K.copy()
    for r in range(60):                                   # reverse the column order inside every row
        a, b = shuffled.indptr[r], shuffled.indptr[r + 1]
        shuffled.indices[a:b] = shuffled.indices[a:b][::-1].copy()
        shuffled.data[a:b] = shuffled.data[a:b][::-1].copy()
    shuffled.has_sorted_indices = False
    ref = sp.triu(K, format="csr")
    ref.sort_indices()
    for M in (K, shuffled, sp.csc_matrix(K)):
        data, indptr, indices = pardiso._upper_triangle(M)
        assert indptr.dtype == indices.dtype == np.int32
        np.testing.assert_array_equal(indptr, ref.indptr)
        np.testing.assert_array_equal(indices, ref.indices)
        np.testing.assert_array_equal(data, ref.data)


@pytest.mark.parametrize("backend", ["superlu", pytest.param("pardiso", marks=needs_mkl)])
def test_primal_blocks_of_the_batch_equal_those_of_one_factorization_per_subdomain(backend, monkeypatch):
    """PrimalConstrainedSolver: Psi and S_PiPi of the batched subdomains (all at once, from K_W) equal
    the per-subdomain construction (one factorization each), with coefficient jumps (rho)."""
    from ddsolve.dd.operators import PrimalConstrainedSolver

    sub = _sub()
    monkeypatch.setattr(local, "SPARSE_BACKEND", backend)
    batched = PrimalConstrainedSolver(sub, sub.vertex, {})
    assert batched.rr._batch is not None
    monkeypatch.setattr(sub, "batch_local", False)           # one factorization per subdomain, no batch
    single = PrimalConstrainedSolver(sub, sub.vertex, {})
    assert single.rr._batch is None
    scale = np.abs(single.S_PiPi).max()
    assert abs(batched.S_PiPi - single.S_PiPi).max() <= 1e-12 * scale
    np.testing.assert_allclose(batched.Psi, single.Psi, rtol=0, atol=1e-11 * np.abs(single.Psi).max())
    rng = np.random.default_rng(4)
    b = rng.standard_normal(sub.n_W)
    x1, x2 = batched.solve(b), single.solve(b)
    assert np.linalg.norm(x1 - x2) <= 1e-10 * np.linalg.norm(x2)


def test_symmetric_superlu_keeps_the_ordering_of_a_positive_definite_matrix():
    """ddsolve.dd.coarse.symmetric_superlu (SuperLU's coarse factorization): on an SPD matrix whose
    off-diagonal entries exceed some diagonal ones (a 40 x 40 grid Laplacian scaled by 10^U(-2, 2)) the
    default threshold pivoting swaps rows and makes 8.9x the fill (a 2D coarse matrix with edge
    averages, 19,477 primal dofs, took 12.3 s against 0.19 s); diagonal pivots keep the minimum
    degree ordering and solve like the direct solve."""
    from ddsolve.dd.coarse import symmetric_superlu

    n = 40
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    rng = np.random.default_rng(0)
    scale = sp.diags(10 ** rng.uniform(-2, 2, n * n))
    A = sp.csc_matrix(scale @ (sp.kron(T, sp.eye(n)) + sp.kron(sp.eye(n), T)) @ scale)
    lu = symmetric_superlu(A)
    default = spla.splu(A, permc_spec="MMD_AT_PLUS_A")
    assert np.array_equal(lu.perm_r, lu.perm_c) and not np.array_equal(default.perm_r, default.perm_c)
    assert default.L.nnz + default.U.nnz > 4 * (lu.L.nnz + lu.U.nnz)        # SciPy 1.x: 355,646 / 39,942
    b = rng.standard_normal(n * n)
    x = lu.solve(b)
    np.testing.assert_allclose(x, spla.spsolve(A, b), rtol=1e-8)
    assert np.linalg.norm(A @ x - b) <= 1e-10 * np.linalg.norm(b)


@pytest.mark.parametrize("kind", ["negative pivots", "zero diagonal"])
def test_symmetric_superlu_pivots_where_the_matrix_is_not_positive_definite(kind):
    """Not positive definite: a negative diagonal pivot (K - 2I), or a zero diagonal entry (a symmetric
    permutation block, where even the diagonal-pivot factorization swaps rows), is factored again with
    the default pivoting and solved as before."""
    from ddsolve.dd.coarse import symmetric_superlu

    K = _laplacian(12, 1e-2)
    if kind == "negative pivots":
        A = sp.csc_matrix(K - 2.0 * sp.eye(K.shape[0]))
    else:
        A = sp.csc_matrix(sp.block_diag([K, sp.csr_matrix([[0.0, 1.0], [1.0, 0.0]])]))
    b = np.random.default_rng(6).standard_normal(A.shape[0])
    lu = symmetric_superlu(A)
    expected = spla.splu(A, permc_spec="MMD_AT_PLUS_A")           # the default pivoting, as before
    np.testing.assert_array_equal(lu.perm_r, expected.perm_r)
    np.testing.assert_allclose(A @ lu.solve(b), b, rtol=1e-8, atol=1e-10)
