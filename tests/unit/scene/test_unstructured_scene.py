"""Unstructured P1 scenes: netgen geometries, METIS partitions, assembly and DD solves."""
import numpy as np
import pytest
import scipy.sparse as sp

from ddsolve.dd import Substructures, solve_bddc, solve_direct, solve_feti, solve_fetidp
from ddsolve.errors import InputError
from ddsolve.scene import assemble, structured_square
from ddsolve.scene.partition import element_graph, is_connected_partition, partition_elements, repair_partition
from ddsolve.scene.unstructured import mesh_geometry, scene_from_mesh, unstructured_scene


def _connected_parts(scene):
    for s in range(scene.n_subdomains):
        assert np.any(scene.element_subdomain == s), f"subdomain {s} empty"
    return is_connected_partition(scene.elements, scene.element_subdomain)


@pytest.mark.parametrize("geometry", ["square", "lshape", "hole"])
def test_poisson_geometries_are_p1_partitioned_and_clamped(geometry):
    sc = unstructured_scene("poisson", geometry=geometry, maxh=0.1, parts=5)
    assert sc.element_type == "P1" and sc.elements.shape[1] == 3
    assert sc.n_subdomains == 5 and sc.n_bodies == 1 and len(sc.contact_pairs) == 0
    assert _connected_parts(sc)
    # Dirichlet nodes are exactly the boundary nodes of the body
    np.testing.assert_array_equal(sc.dirichlet, sc.boundary_nodes(0))
    x, y = sc.coords[sc.dirichlet].T
    on_square = (np.abs(x) < 1e-9) | (np.abs(x - 1) < 1e-9) | (np.abs(y) < 1e-9) | (np.abs(y - 1) < 1e-9)
    if geometry == "square":
        assert on_square.all()
    if geometry == "hole":
        r = np.hypot(x - 0.5, y - 0.5)
        assert np.any(np.abs(r - 0.25) < 1e-9) and np.all(on_square | (np.abs(r - 0.25) < 1e-9))
    if geometry == "lshape":
        assert not np.any((sc.coords[:, 0] > 0.5 + 1e-9) & (sc.coords[:, 1] > 0.5 + 1e-9))


def test_partition_is_deterministic():
    a = unstructured_scene("poisson", geometry="hole", maxh=0.05, parts=9)
    b = unstructured_scene("poisson", geometry="hole", maxh=0.05, parts=9)
    np.testing.assert_array_equal(a.element_subdomain, b.element_subdomain)
    np.testing.assert_array_equal(a.coords, b.coords)


def test_contact_line_is_conforming_with_node_pairs():
    sc = unstructured_scene("contact", maxh=0.1, parts=3)
    assert sc.n_bodies == 2 and sc.n_subdomains == 6
    assert _connected_parts(sc)
    pairs = sc.contact_pairs
    a, b = pairs[:, 0], pairs[:, 1]
    body_of_node = np.empty(sc.n_nodes, dtype=int)
    body_of_node[sc.elements.ravel()] = np.repeat(sc.subdomain_body[sc.element_subdomain], 3)
    assert np.all(body_of_node[a] == 0) and np.all(body_of_node[b] == 1)
    np.testing.assert_array_equal(sc.coords[a], sc.coords[b])            # node to node
    np.testing.assert_allclose(sc.coords[a, 0], 1.0, atol=1e-12)
    assert np.all(np.diff(sc.coords[a, 1]) > 0)                            # ordered by y, each node once
    assert sc.coords[a, 1].min() == pytest.approx(0) and sc.coords[a, 1].max() == pytest.approx(1)
    # every node of body 0 on x = 1 is paired, and the bodies share no node
    on_line0 = np.flatnonzero((body_of_node == 0) & (np.abs(sc.coords[:, 0] - 1) < 1e-12))
    np.testing.assert_array_equal(np.sort(on_line0), np.sort(a))
    # clamped on x = 0 only (body 0), Omega^2 floats
    assert np.all(np.abs(sc.coords[sc.dirichlet, 0]) < 1e-9)
    assert not sc.dirichlet[body_of_node == 1].any()
    # Dostal patches are mesh lines: the load integral is exact
    d1 = sc.coords[sc.elements[:, 1]] - sc.coords[sc.elements[:, 0]]
    d2 = sc.coords[sc.elements[:, 2]] - sc.coords[sc.elements[:, 0]]
    area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    assert float(np.sum(sc.f * area)) == pytest.approx(-3.0 * 0.25 - 1.0 * 0.25, rel=1e-12)


def test_multibody_bodies_are_split_with_matching_copies():
    nb = 2
    sc = unstructured_scene("multibody", bodies=nb, maxh=0.1, parts=2)
    assert sc.n_bodies == nb * nb and sc.n_subdomains == 2 * nb * nb
    assert _connected_parts(sc)
    body_of_node = np.empty(sc.n_nodes, dtype=int)
    body_of_node[sc.elements.ravel()] = np.repeat(sc.subdomain_body[sc.element_subdomain], 3)
    # every element lies in its body's square (body b = by * nb + bx)
    c = sc.coords[sc.elements].mean(axis=1)
    eb = sc.subdomain_body[sc.element_subdomain]
    np.testing.assert_array_equal(np.floor(c[:, 1] * nb) * nb + np.floor(c[:, 0] * nb), eb)
    a, b = sc.contact_pairs.T
    assert np.all(body_of_node[a] < body_of_node[b])
    np.testing.assert_array_equal(sc.coords[a], sc.coords[b])
    # copies at one location: one per body touching it; the centre (0.5, 0.5) has four
    centre = np.flatnonzero(np.all(np.abs(sc.coords - 0.5) < 1e-12, axis=1))
    assert sorted(body_of_node[centre]) == [0, 1, 2, 3]
    # Dirichlet on the outer boundary only
    x, y = sc.coords[sc.dirichlet].T
    assert np.all((np.abs(x) < 1e-9) | (np.abs(x - 1) < 1e-9) | (np.abs(y) < 1e-9) | (np.abs(y - 1) < 1e-9))


def test_partition_repair_merges_stray_pieces():
    sc = unstructured_scene("poisson", maxh=0.1, parts=1)
    first, second = element_graph(sc.elements)
    label = (sc.coords[sc.elements].mean(axis=1)[:, 0] > 0.5).astype(np.int64)
    label[np.argmin(sc.coords[sc.elements].mean(axis=1)[:, 0])] = 1   # one stray element of part 1 at x ~ 0
    assert not is_connected_partition(sc.elements, label)
    fixed = repair_partition(label, first, second, 2)
    assert is_connected_partition(sc.elements, fixed)
    assert np.sum(fixed != label) == 1 and np.bincount(fixed).min() > 0


def test_partition_bad_parts():
    els = mesh_geometry("poisson", maxh=0.5).Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    with pytest.raises(InputError, match="parts"):
        partition_elements(els, 0)
    with pytest.raises(InputError, match="only"):
        partition_elements(els, els.shape[0] + 1)
    with pytest.raises(InputError, match="geometry"):
        unstructured_scene("poisson", geometry="circle")
    with pytest.raises(InputError, match="maxh"):
        unstructured_scene("poisson", maxh=-1)
    with pytest.raises(InputError, match="rho"):
        unstructured_scene("poisson", maxh=0.25, parts=2, rho=[1.0, 2.0, 3.0])   # (maxh 0.5: no interior node)
    with pytest.raises(InputError, match="bodies"):
        unstructured_scene("poisson", bodies=2)
    with pytest.raises(InputError, match="negative integral"):
        unstructured_scene("contact", maxh=0.5, parts=1, f=1.0)


def test_boundary_nodes_vectorised_matches_per_body_definition():
    sc = structured_square(2, 2, 3)
    for b in range(sc.n_bodies):
        els = sc.elements[sc.subdomain_body[sc.element_subdomain] == b]
        edges = np.sort(np.concatenate([els[:, [k, (k + 1) % 4]] for k in range(4)]), axis=1)
        uniq, counts = np.unique(edges, axis=0, return_counts=True)
        expected = np.zeros(sc.n_nodes, dtype=bool)
        expected[uniq[counts == 1].ravel()] = True
        np.testing.assert_array_equal(sc.boundary_nodes(b), expected)


@pytest.mark.parametrize("problem,kw", [("poisson", dict(geometry="hole")), ("contact", {}),
                                        ("multibody", dict(bodies=2))])
def test_assembly_matches_global_ngsolve_assembly(problem, kw):
    import ngsolve as ngs

    if problem == "contact":    # element-wise Dostal loads
        sc = unstructured_scene(problem, maxh=0.15, parts=3)
    else:                       # a coefficient function
        sc = unstructured_scene(problem, maxh=0.15, parts=3, f=lambda x, y: 1 + x * y, **kw)
    local = assemble(sc)
    assert local.n_templates == sc.n_subdomains
    # sum of the scattered subdomain matrices and loads
    rows, cols, vals, load = [], [], [], np.zeros(sc.n_nodes)
    for s, nd in enumerate(local.nodes):
        K = local.stiffness[s].tocoo()
        rows.append(nd[K.row]), cols.append(nd[K.col]), vals.append(K.data)
        np.add.at(load, nd, local.loads[s])
    A_sum = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(sc.n_nodes, sc.n_nodes))
    # the same (split) mesh assembled globally by NGSolve
    from netgen.meshing import Mesh as NGMesh
    ngmesh = NGMesh(dim=2)
    ngmesh.AddPoints(np.column_stack([sc.coords, np.zeros(sc.n_nodes)]))
    ngmesh.AddElements(dim=2, index=ngmesh.AddRegion("all", 2), data=sc.elements.astype(np.int32), base=0)
    mesh = ngs.Mesh(ngmesh)
    fes = ngs.H1(mesh, order=1)
    u, v = fes.TnT()
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx).Assemble()
    r, c, w = a.mat.COO()
    A = sp.csr_matrix((np.asarray(w), (np.asarray(r), np.asarray(c))), shape=(sc.n_nodes, sc.n_nodes))
    assert abs(A - A_sum).max() < 1e-12 * abs(A).max()
    if isinstance(sc.f, np.ndarray):
        gf = ngs.GridFunction(ngs.L2(mesh, order=0))
        gf.vec.FV().NumPy()[:] = sc.f
        fcf = gf
    else:
        fcf = sc.f(ngs.x, ngs.y)
    lf = ngs.LinearForm(fcf * v * ngs.dx).Assemble()
    np.testing.assert_allclose(load, lf.vec.FV().NumPy(), rtol=0, atol=1e-14 * np.abs(load).max())
    # unit-coefficient local matrices are symmetric with constants in their kernel
    for K in local.stiffness:
        assert abs(K - K.T).max() < 1e-12
        assert np.abs(K @ np.ones(K.shape[0])).max() < 1e-12


SOLVERS = {"fetidp": solve_fetidp, "bddc": solve_bddc, "feti": solve_feti}


@pytest.mark.parametrize("method", sorted(SOLVERS))
@pytest.mark.parametrize("geometry,parts", [("square", 6), ("lshape", 5), ("hole", 7), ("square", 16)])
def test_dd_solvers_match_direct_on_unstructured_poisson(method, geometry, parts):
    rho = np.random.default_rng(3).choice([1.0, 10.0], parts)
    sc = unstructured_scene("poisson", geometry=geometry, maxh=0.07, parts=parts, rho=rho,
                            f=lambda x, y: 1 + x * y)
    sub = Substructures(assemble(sc))
    if parts == 16:
        assert sub.floating_sub.any()          # METIS leaves interior subdomains without Dirichlet nodes
    A = sub.global_matrix()
    u_direct = solve_direct(sub).u
    out = SOLVERS[method](sub, rtol=1e-10)
    assert out.krylov.converged
    e = out.u - u_direct
    assert np.sqrt(e @ A @ e / (u_direct @ A @ u_direct)) < 1e-8


def test_scene_from_mesh_file(tmp_path):
    from conftest import two_squares

    path = tmp_path / "two.vol"
    two_squares(0.2).ngmesh.Save(str(path))

    sc = scene_from_mesh(path, bodies=["left", "right"], dirichlet="wall", contact="gap", parts=2)
    assert sc.n_bodies == 2 and sc.n_subdomains == 4 and _connected_parts(sc)
    np.testing.assert_allclose(sc.coords[sc.contact_pairs[:, 0], 0], 1.0, atol=1e-12)
    np.testing.assert_array_equal(sc.coords[sc.contact_pairs[:, 0]], sc.coords[sc.contact_pairs[:, 1]])
    assert np.all(np.abs(sc.coords[sc.dirichlet, 0]) < 1e-9) and sc.dirichlet.sum() >= 6

    with pytest.raises(InputError, match="no such file"):
        scene_from_mesh(tmp_path / "missing.vol")
    junk = tmp_path / "junk.vol"
    junk.write_text("hello world\n")
    with pytest.raises(InputError, match="not a netgen mesh"):
        scene_from_mesh(junk)
    with pytest.raises(InputError, match="no material named 'middle'"):
        scene_from_mesh(path, bodies=["left", "middle"])
    with pytest.raises(InputError, match="no boundary named 'floor'"):
        scene_from_mesh(path, dirichlet="floor")
    with pytest.raises(InputError, match="no boundary named 'slit'"):
        scene_from_mesh(path, contact="slit")


def test_scene_from_mesh_rejects_non_conforming_contact(tmp_path):
    from netgen.occ import X, MoveTo, OCCGeometry

    # two bodies meshed separately with different sizes, joined into one file: nodes on x = 1 do not match
    meshes = []
    for x0, h, name in ((0, 0.3, "left"), (1, 0.13, "right")):
        face = MoveTo(x0, 0).Rectangle(1, 1).Face()
        face.faces.name = name
        face.edges.Min(X).name = "gap" if x0 == 1 else "wall"
        if x0 == 0:
            face.edges.Max(X).name = "gap"
        meshes.append(OCCGeometry(face, dim=2).GenerateMesh(maxh=h))
    from netgen.meshing import Mesh as NGMesh
    joined = NGMesh(dim=2)
    gap = joined.AddRegion("gap", dim=1)
    for k, m in enumerate(meshes):
        region = joined.AddRegion(["left", "right"][k], dim=2)
        base = len(joined.Coordinates()) if k else 0
        pts = m.Coordinates()
        joined.AddPoints(np.column_stack([pts, np.zeros(len(pts))]))
        els = m.Elements2D().NumPy()["nodes"][:, :3].astype(np.int32) - 1 + base
        joined.AddElements(dim=2, index=region, data=els, base=0)
        seg = m.Elements1D().NumPy()
        names = [m.GetBCName(i - 1) for i in seg["index"]]
        gap_seg = seg["nodes"][[n == "gap" for n in names], :2].astype(np.int32) - 1 + base
        joined.AddElements(dim=1, index=gap, data=gap_seg, base=0)
    path = tmp_path / "nonconforming.vol"
    joined.Save(str(path))
    with pytest.raises(InputError, match=r"contact: .*not a conforming interface .*near \(1, "):
        scene_from_mesh(path, bodies=["left", "right"], contact="gap", parts=1)


@pytest.mark.parametrize("nb", [2, 3])                 # nb = 3: the centre body floats
def test_hybrid_matches_direct_on_unstructured_multibody(nb):
    from ddsolve.multibody import GlobalInterface
    from ddsolve.multibody.direct import solve_constrained_direct
    from ddsolve.multibody.hybrid import HybridSolver

    sc = unstructured_scene("multibody", bodies=nb, maxh=0.1, parts=3, f=lambda x, y: 1 + x * y)
    sub = Substructures(assemble(sc))
    gi = GlobalInterface(sub)
    hs = HybridSolver(sub, gi)
    assert hs.floating.size == (1 if nb == 3 else 0)
    A = sub.global_matrix()
    for case in ("full", "middle"):
        active = gi.contact_mask(case)
        res = hs.solve(active, rtol=1e-10)
        ref = solve_constrained_direct(sub, gi, active).u
        assert res.krylov.converged
        e = res.u - ref
        assert np.sqrt(e @ A @ e / (ref @ A @ ref)) < 1e-8


def test_contact_active_set_matches_direct_on_unstructured_membranes():
    from ddsolve.contact.active_set import solve_contact_active_set
    from ddsolve.contact.direct import solve_contact_direct
    from ddsolve.contact.problem import ContactProblem

    sc = unstructured_scene("contact", maxh=0.1, parts=4)
    problem = ContactProblem(Substructures(assemble(sc)))
    assert problem.n_contact == len(sc.contact_pairs)
    ref = solve_contact_direct(problem)
    assert ref.converged, ref.reason
    assert problem.kkt(ref.u, ref.lam).max < 1e-8
    sol = solve_contact_active_set(problem, rtol=1e-10, pcg_rtol=1e-10)
    assert sol.converged, sol.reason
    np.testing.assert_array_equal(sol.active, ref.active)
    assert problem.kkt(sol.u, sol.lam).max < 1e-7
    assert np.abs(sol.u - ref.u).max() < 1e-7 * np.abs(ref.u).max()


@pytest.mark.parametrize("problem,kw", [("poisson", dict(geometry="hole")), ("contact", {}),
                                        ("multibody", dict(bodies=2))])
def test_split_shares_its_edge_sort_with_the_element_graph(problem, kw, monkeypatch):
    from ddsolve.scene import unstructured as U

    ngmesh = mesh_geometry(problem, maxh=0.1, **kw)
    data = U.netgen_arrays(ngmesh)
    body_of_material = np.array([int(name[4:]) for name in data.material_names])
    dirichlet = ["clamp"] if problem == "contact" else "boundary"
    contact = "contact" if problem == "contact" else None
    split = U.split_bodies(data, body_of_material, dirichlet=dirichlet, contact=contact)
    # the element pairs of each body are exactly the edge-adjacency graph of its elements
    first, second = split.adjacent
    assert np.all(first < second)
    assert np.all(split.element_body[first] == split.element_body[second])
    got = np.sort(first * split.elements.shape[0] + second)
    expected = []
    for b in range(int(split.element_body.max()) + 1):
        members = np.flatnonzero(split.element_body == b)
        f, s = element_graph(split.elements[members])
        expected.append(members[f] * split.elements.shape[0] + members[s])
    np.testing.assert_array_equal(got, np.sort(np.concatenate(expected)))
    # node copies numbered through the dense marker equal those of the sort
    monkeypatch.setattr(U, "DENSE_COPY_FACTOR", 0)
    by_sort = U.split_bodies(data, body_of_material, dirichlet=dirichlet, contact=contact)
    for x, y in zip(split[:5], by_sort[:5]):
        np.testing.assert_array_equal(x, y)


def test_repair_reads_the_inner_graph_off_the_full_graph():
    from ddsolve.scene.partition import _adjacency, _inner_graph

    sc = unstructured_scene("poisson", geometry="lshape", maxh=0.05, parts=1)
    first, second = element_graph(sc.elements)
    n = sc.elements.shape[0]
    label = np.minimum((sc.coords[sc.elements].mean(axis=1)[:, 0] * 5).astype(np.int64), 4)   # stripes
    flip = np.random.default_rng(4).choice(n, size=30, replace=False)
    label[flip] = (label[flip] + 2) % 5                                  # stray elements
    inner = label[first] == label[second]
    a = _inner_graph(n, first, second, inner, label, _adjacency(n, first, second))
    b = _adjacency(n, first[inner], second[inner])
    for x, y in ((a.indptr, b.indptr), (a.indices, b.indices), (a.data, b.data)):
        np.testing.assert_array_equal(x, y)
    # the repair gives the same labels with and without the prebuilt graph
    fixed = repair_partition(label, first, second, 5)
    assert is_connected_partition(sc.elements, fixed) and not is_connected_partition(sc.elements, label)
    np.testing.assert_array_equal(fixed, repair_partition(label, first, second, 5,
                                                          graph=_adjacency(n, first, second)))


def test_check_conforming_finds_hanging_and_duplicate_nodes():
    """Boundary edges (of one element each) meeting only at shared nodes pass; a node inside another boundary
    edge, or a second node on top of one, is refused with where it is."""
    from ddsolve.scene.unstructured import _check_conforming

    coords = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [1, 0.5], [1, 0.0]], dtype=float)
    square = (np.array([0, 1, 2, 3]), np.array([1, 2, 3, 0]))              # the outer boundary of a square
    _check_conforming(coords, *square)
    with pytest.raises(InputError, match=r"^mesh: the mesh is not conforming near \(1, 0.5\): 1 boundary node"):
        _check_conforming(coords, np.r_[square[0], 1, 4], np.r_[square[1], 4, 2])   # (1, 0.5) hangs on 1-2
    with pytest.raises(InputError, match=r"^mesh: the mesh is not conforming near \(1, 0\): 2 boundary node"):
        _check_conforming(coords, np.r_[square[0], 5], np.r_[square[1], 2])          # node 5 on top of node 1


def _graded_square(n_fine: int):
    """The unit square's boundary: the bottom side's first 1/100 in n_fine edges, then one edge to (1, 0)."""
    xs = np.linspace(0.0, 0.01, n_fine + 1)
    coords = np.r_[np.c_[xs, np.zeros_like(xs)], [[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]]
    a = np.arange(coords.shape[0])
    return coords, a, (a + 1) % a.size


def test_check_conforming_on_a_graded_boundary(monkeypatch):
    """Edges of very different lengths: the candidates stay O(m) (one radius for all, half the longest
    edge, gave every fine node every fine edge: about m^2 pairs, out of memory at 16,000), and hanging
    nodes are still found both among the short edges and on the long one."""
    import scipy.spatial

    from ddsolve.scene.unstructured import _check_conforming

    pairs = []

    class Counted(scipy.spatial.cKDTree):
        def sparse_distance_matrix(self, other, r, **kw):
            out = super().sparse_distance_matrix(other, r, **kw)
            pairs.append(out.size)
            return out

    monkeypatch.setattr(scipy.spatial, "cKDTree", Counted)
    n_fine = 2000
    coords, a, b = _graded_square(n_fine)
    _check_conforming(coords, a, b)
    assert sum(pairs) <= 4 * a.size                         # was about n_fine^2 / 2 = 2e6
    x = 0.5 * (coords[10, 0] + coords[11, 0])                                     # inside fine edge 10-11
    hang_fine = np.r_[coords, [[x, 0.0], [x, 5e-6]]]
    k = coords.shape[0]
    with pytest.raises(InputError, match=r"not conforming near \(5.25e-05, 0\): 1 boundary node"):
        _check_conforming(hang_fine, np.r_[a, k, k + 1], np.r_[b, k + 1, 10])      # k -> k + 1 -> 10
    hang_long = np.r_[coords, [[0.5, 0.0], [0.5, 0.5]]]                              # inside the long edge
    with pytest.raises(InputError, match=r"not conforming near \(0.5, 0\): 1 boundary node"):
        _check_conforming(hang_long, np.r_[a, k, k + 1], np.r_[b, k + 1, n_fine + 2])   # k -> k + 1 -> (1, 1)
