"""Structured (Q1) assembly: vectorized template detection, representative-only stiffness,
loads through the element load matrix, and the block-diagonal K_W, each against a
straightforward per-subdomain reference."""
import numpy as np
import pytest
import scipy.sparse as sp

from ddsolve.dd.substructure import Substructures
from ddsolve.scene import assemble, detect_templates, structured_square


def _reference_templates(scene, nodes):
    """The per-subdomain loop of the original definition (bytes of relative coordinates
    and of the sorted local connectivity, numbered by first occurrence)."""
    size = float(np.ptp(scene.coords, axis=0).max())
    keys, template = {}, np.empty(scene.n_subdomains, dtype=np.int64)
    for s, nd in enumerate(nodes):
        rel = np.round((scene.coords[nd] - scene.coords[nd].min(axis=0)) / size, 10)
        els = scene.elements[scene.element_subdomain == s]
        srt = np.argsort(nd)
        local = srt[np.searchsorted(nd[srt], els)]
        local = local[np.lexsort(local.T[::-1])]
        template[s] = keys.setdefault((len(nd), len(els), rel.tobytes(), local.tobytes()), len(keys))
    return template


def _reference_local(scene, s, nodes, f):
    """Stiffness and load of subdomain s assembled on a mesh of that subdomain alone."""
    import ngsolve as ngs
    from netgen.meshing import Mesh as NGMesh

    nd = nodes[s]
    els = np.flatnonzero(scene.element_subdomain == s)
    srt = np.argsort(nd)
    local = srt[np.searchsorted(nd[srt], scene.elements[els])]
    ngmesh = NGMesh(dim=2)
    ngmesh.AddPoints(np.column_stack([scene.coords[nd], np.zeros(len(nd))]))
    region = ngmesh.AddRegion("s", 2)
    ngmesh.AddElements(dim=2, index=region, data=local.astype(np.int32), base=0)
    mesh = ngs.Mesh(ngmesh)
    fes = ngs.H1(mesh, order=1)
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += ngs.grad(u) * ngs.grad(v) * ngs.dx
    a.Assemble()
    rows, cols, vals = a.mat.COO()
    K = sp.csr_matrix((np.asarray(vals), (np.asarray(rows), np.asarray(cols))), shape=(fes.ndof, fes.ndof))
    if isinstance(f, np.ndarray):
        gf = ngs.GridFunction(ngs.L2(mesh, order=0))
        gf.vec.FV().NumPy()[:] = f[els]
        cf = gf
    elif callable(f):
        cf = f(ngs.x, ngs.y)
    else:
        cf = ngs.CoefficientFunction(float(f))
    lf = ngs.LinearForm(fes)
    lf += cf * v * ngs.dx
    lf.Assemble()
    return K, np.array(lf.vec.FV().NumPy())


def _perturbed_scene(f):
    """3 x 3 subdomains of 4 x 4 elements; subdomains 1 and 5 are made distinct (an interior
    node moved, an element's nodes listed from another corner), so the templates interleave."""
    sc = structured_square(1, 3, 4, f=f)
    n = 12
    sc.coords[2 * (n + 1) + 6] += [0.01, -0.02]             # interior node of subdomain 1 (column 1, row 0)
    e = int(np.flatnonzero(sc.element_subdomain == 5)[3])
    sc.elements[e] = np.roll(sc.elements[e], 1)              # same quad, other first corner
    return sc


@pytest.mark.parametrize("f", [2.5, "array", "callable"])
def test_templates_stiffness_and_loads_against_per_subdomain_assembly(f):
    import ngsolve as ngs

    if f == "array":
        f = np.random.default_rng(7).uniform(-1.0, 1.0, 144)
    elif f == "callable":
        f = lambda x, y: ngs.sin(3 * x) * y + x      # noqa: E731
    sc = _perturbed_scene(f)
    local = assemble(sc)
    nodes = sc.subdomain_nodes()
    expected = _reference_templates(sc, nodes)
    np.testing.assert_array_equal(local.template, expected)
    np.testing.assert_array_equal(detect_templates(sc, nodes), expected)
    assert local.template.tolist() == [0, 1, 0, 0, 0, 2, 0, 0, 0]
    for s in range(sc.n_subdomains):
        np.testing.assert_array_equal(local.nodes[s], nodes[s])
        K, load = _reference_local(sc, s, nodes, f)
        Kt = local.stiffness[local.template[s]]
        assert abs(Kt - K).max() <= 1e-14 * abs(K).max()
        np.testing.assert_allclose(local.loads[s], load, rtol=0, atol=1e-14 * np.abs(load).max())


def test_block_diagonal_with_interleaved_templates():
    sc = _perturbed_scene(1.0)
    sc.rho = np.arange(1.0, 10.0)
    local = assemble(sc)
    for templates in (True, False):
        sub = Substructures(local, templates=templates)
        blocks = [sc.rho[s] * local.stiffness[local.template[s]] for s in range(sc.n_subdomains)]
        keep = ~sc.dirichlet[np.concatenate(local.nodes)]
        expected = sp.block_diag(blocks, format="csr")[keep][:, keep]
        assert sub.K_W.shape == expected.shape
        assert sub.K_W.has_canonical_format
        assert abs(sub.K_W - expected).max() == 0.0


def test_first_equal_row_survives_a_hash_collision():
    from ddsolve.scene.assembly import _first_equal_row

    w = np.random.default_rng(12345).integers(1, 2**62, 2, dtype=np.int64)
    rows = np.array([[w[1], 0], [0, w[0]], [w[1], 0], [3, 4]], dtype=np.int64)   # rows 0 and 1: same hash
    with np.errstate(over="ignore"):
        assert (rows[0] * w).sum() == (rows[1] * w).sum()
    np.testing.assert_array_equal(_first_equal_row(rows), [0, 1, 0, 3])
