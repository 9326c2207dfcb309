"""Template-free (batched) local solves and primal constraints on irregular subdomains."""
import dataclasses

import numpy as np
import pytest

from ddsolve.api import build_scene
from ddsolve.dd import Substructures
from ddsolve.dd.bddc import solve_bddc
from ddsolve.dd.direct import solve_direct
from ddsolve.dd.feti import solve_feti
from ddsolve.dd.fetidp import solve_fetidp
from ddsolve.scene import assemble
from ddsolve.spec import ProblemSpec

SOLVERS = {"feti": solve_feti, "fetidp": solve_fetidp, "bddc": solve_bddc}


def _scene(ns, m, rho=1.0):
    return build_scene(ProblemSpec.from_mapping(dict(subdomains=ns, elements=m, rho=rho, f="random:1")))


def _relabel(scene, labels, rho=None):
    """The same Q1 grid with another subdomain label per element (one body)."""
    n = int(labels.max()) + 1
    rho = np.ones(n) if rho is None else rho
    return dataclasses.replace(scene, element_subdomain=np.asarray(labels, dtype=np.int64),
                               subdomain_body=np.zeros(n, dtype=np.int64), rho=np.asarray(rho, float),
                               subdomain_grid=None)


def _centers(scene):
    return scene.coords[scene.elements].mean(axis=1)


def rings(scene):
    """Outer ring (Dirichlet), a middle ring and a centre square: two floating subdomains with
    one neighbour each and no cross point at all."""
    c = np.abs(_centers(scene) - 0.5).max(axis=1)
    return _relabel(scene, np.where(c > 0.3, 0, np.where(c > 0.15, 1, 2)), rho=[1.0, 10.0, 0.1])


def metis(scene, nparts):
    """pymetis partition of the element graph (elements sharing an edge); subdomains must be connected
    (METIS may return disconnected parts, whose local kernels the primal rule does not cover)."""
    pymetis = pytest.importorskip("pymetis")
    import scipy.sparse as sp
    import scipy.sparse.csgraph  # noqa: F401
    els = scene.elements
    ne = els.shape[0]
    E = sp.csr_matrix((np.ones(els.size), (np.repeat(np.arange(ne), 4), els.ravel())))
    A = (E @ E.T).tocsr()
    A.setdiag(0)
    A = (A >= 2).astype(np.int64).tocsr()
    A.eliminate_zeros()
    adjacency = pymetis.CSRAdjacency(A.indptr.astype(np.int64), A.indices.astype(np.int64))
    _, parts = pymetis.part_graph(nparts, adjacency, options=pymetis.Options(seed=1))
    labels = np.asarray(parts)
    for s in range(nparts):
        e = els[labels == s]
        E_s = sp.csr_matrix((np.ones(e.size), (np.repeat(np.arange(len(e)), 4), e.ravel())))
        assert sp.csgraph.connected_components((E_s @ E_s.T) >= 2)[0] == 1, f"part {s} is disconnected"
    rho = 10.0 ** np.random.default_rng(7).integers(-2, 3, size=nparts)
    return _relabel(scene, labels, rho=rho)


def wedges(scene, n=7):
    """Deterministic irregular labels: angular sectors around an off-centre point, plus a centre disc."""
    d = _centers(scene) - np.array([0.37, 0.58])
    angle = np.floor((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * n).astype(int) % n
    return _relabel(scene, np.where(np.hypot(*d.T) < 0.17, n, angle))


# --------------------------------------------------------------------- template-free path
@pytest.mark.parametrize("method", sorted(SOLVERS))
@pytest.mark.parametrize("ns,m,rho", [(3, 4, "checkerboard:100"), (4, 5, 1.0), (5, 3, "checkerboard:0.01"),
                                      (6, 6, "checkerboard:100")])   # the last: sparse batched factors
def test_template_free_equals_templates(method, ns, m, rho):
    local = assemble(_scene(ns, m, rho))
    a = SOLVERS[method](Substructures(local), rtol=1e-10)
    b = SOLVERS[method](Substructures(local, templates=False), rtol=1e-10)
    assert a.krylov.iterations == b.krylov.iterations
    np.testing.assert_allclose(b.u, a.u, rtol=0, atol=1e-12 * np.abs(a.u).max())


def test_one_batched_factorization_per_kind(count_factorizations):
    local = assemble(_scene(6, 4))
    made = count_factorizations()
    sub = Substructures(local, templates=False)
    out = solve_fetidp(sub, rtol=1e-10)
    # A_rr (primal-constrained) and A_II (Dirichlet): one block-diagonal factorization each, plus none per
    # subdomain (the coarse problem is not a subdomain factorization)
    assert len(made) == 2, made
    assert out.n_factorizations == 3
    made.clear()
    out = solve_feti(Substructures(local, templates=False), rtol=1e-10)
    # K^+ (one node fixed per floating subdomain), A_II and the final error check's A_rr: the check runs on
    # every general mesh (no templates; ddsolve.dd.check.needs_check), whatever the coefficient
    assert len(made) == 3, made
    assert out.extra["error_estimate"] < 1e-8


@pytest.mark.parametrize("ns,m", [(4, 6), (5, 9)])      # dense (<= DENSE_LIMIT unknowns) and sparse factor
def test_block_solves_match_per_subdomain_factorization(ns, m):
    from ddsolve.dd.local import DENSE_LIMIT, BatchedSolver, _BlockView
    local = assemble(_scene(ns, m, "checkerboard:100"))
    sub = Substructures(local, templates=False)
    solver = BatchedSolver(sub, ~sub.interface, {})
    rng = np.random.default_rng(3)
    b = rng.standard_normal((sub.n_W, 3))
    x = solver.solve(b)
    assert (solver._batch[0].kind == "sparse") == (solver._batch[1].size > DENSE_LIMIT)
    for g in solver.groups:
        assert isinstance(g.factor, _BlockView)
        K = sub.stiffness[int(sub.template[g.members[0]])][g.loc][:, g.loc].toarray()
        np.testing.assert_allclose(K @ g.factor.solve(b[g.index[:, 0]]), b[g.index[:, 0]], atol=1e-11)
        np.testing.assert_allclose(sub.rho[g.members[0]] * K @ x[g.index[:, 0]], b[g.index[:, 0]], atol=1e-11)


# --------------------------------------------------------------------- irregular subdomains
IRREGULAR = {"rings": lambda: rings(_scene(1, 20)), "metis": lambda: metis(_scene(1, 24), 18),
             "wedges": lambda: wedges(_scene(1, 20))}


@pytest.mark.parametrize("templates", [True, False])
@pytest.mark.parametrize("method", sorted(SOLVERS))
@pytest.mark.parametrize("case", sorted(IRREGULAR))
def test_irregular_matches_direct(case, method, templates):
    sub = Substructures(assemble(IRREGULAR[case]()), templates=templates)
    assert sub.floating_sub.any()
    ref = solve_direct(sub).u
    out = SOLVERS[method](sub, rtol=1e-10)
    assert out.krylov.converged
    A = sub.global_matrix()
    e = out.u - ref
    assert np.sqrt(e @ A @ e) / np.sqrt(ref @ A @ ref) < 1e-8


def test_missing_cross_points_get_primal_nodes():
    sub = Substructures(assemble(IRREGULAR["rings"]()))
    assert not sub.cross_point.any()                       # no node shared by three subdomains
    assert sub.n_primal >= 2
    for s in np.flatnonzero(sub.floating_sub):             # each floating subdomain has a primal node
        assert sub.vertex[sub.sub_of_W == s].any()
    # the primal graph connects every floating subdomain to the Dirichlet one
    comp = sub._primal_components(sub.vertex)
    assert np.unique(comp).size == 1


def test_structured_primal_nodes_are_the_cross_points():
    sub = Substructures(assemble(_scene(4, 3)))
    np.testing.assert_array_equal(sub.vertex, sub.cross_point)
    assert sub.n_primal == 9


def test_unknown_primal_kind_is_rejected():
    with pytest.raises(ValueError, match="primal"):
        Substructures(assemble(_scene(2, 2)), primal="faces")


@pytest.mark.parametrize("shape", [(300,), (300, 5), (300, 219), (300, 1000)])
def test_blocked_superlu_solve_equals_one_call(monkeypatch, shape):
    """Column blocks (here of 65536 // 300 = 218 columns, or 8 when forced) give each column the
    solution of one SuperLU call on all of B."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from ddsolve.dd import local

    rng = np.random.default_rng(3)
    A = sp.random(300, 300, density=0.02, random_state=rng)
    K = (A @ A.T + 300 * sp.eye(300)).tocsc()
    factor = spla.splu(K)
    B = np.asfortranarray(rng.standard_normal(shape))
    X = local._blocked_solve(factor, B)
    assert X.shape == B.shape
    np.testing.assert_allclose(X, factor.solve(B), rtol=1e-13, atol=0)
    np.testing.assert_allclose(K @ X, B, rtol=0, atol=1e-10)
    monkeypatch.setattr(local, "SUPERLU_BLOCK_ENTRIES", 1)           # blocks of the minimum, 8 columns
    np.testing.assert_allclose(local._blocked_solve(factor, B), factor.solve(B), rtol=1e-13, atol=0)


@pytest.mark.parametrize("explicit", [True, False])
@pytest.mark.parametrize("labels", ["structured", "wedges"])
def test_dual_solve_equals_the_full_solve_on_the_dual_entries(explicit, labels, monkeypatch):
    """fetidp.dual_solve (A~^{-1} restricted to B's columns, dense blocks or the full solve) gives the
    full W-level solve's values on the dual entries, and zero elsewhere, for b supported there."""
    from ddsolve.dd import operators
    from ddsolve.dd.fetidp import dual_solve
    from ddsolve.dd.primal import PrimalConstrainedSolver

    if explicit:                         # the pays-off rule takes the blocks at once
        monkeypatch.setattr(operators, "EXPLICIT_SETUP_MATVECS", 10 ** 6)
    else:                                # it refuses them (and never switches here)
        monkeypatch.setattr(operators, "EXPLICIT_SETUP_MATVECS", 0)
        monkeypatch.setattr(operators, "EXPLICIT_MAX_BLOCK", 0)
    scene = _scene(4, 6, rho="checkerboard:100")
    scene = wedges(scene) if labels == "wedges" else scene
    sub = Substructures(assemble(scene))
    B, _ = sub.jump_operators(sub.interface & ~sub.vertex)
    solver = PrimalConstrainedSolver(sub, sub.vertex, {})
    solve = dual_solve(solver, B.tocsr())
    mask = np.zeros(sub.n_W, dtype=bool)
    mask[B.tocsr().indices] = True
    assert solver.interface(mask).explicit == explicit
    b = B.T @ np.random.default_rng(2).standard_normal(B.shape[0])
    x, full = solve(b), solver.solve(b)
    np.testing.assert_allclose(x[mask], full[mask], rtol=0, atol=1e-11 * np.abs(full).max())
    assert not x[~mask].any()
