"""Local assembly with NGSolve: subdomain stiffness matrices and load vectors.

The scene is turned into one NGSolve mesh in which every subdomain has its own
copy of its nodes (a "broken" mesh) and its own material ``s<k>``. A first-order
H1 space on that mesh is exactly the unassembled space W = prod_i W^(i) of
Section 2.2.2, so one NGSolve assembly yields the block-diagonal matrix
diag(A^(i)) and the stacked local loads f^(i) of (2.5) without any Python loop
over elements.

Sharing. Subdomains that are translates of each other (same node coordinates
relative to their lower-left corner, same element connectivity) form one
*template*. The coefficient is constant per subdomain, so A^(i) = rho_i K_t with
K_t the unit-coefficient matrix of the template: the stiffness is assembled once
per template, on one representative subdomain, and factorizations are later
shared in the same way (:mod:`ddsolve.dd.local`).

P1 triangles (netgen meshes, :mod:`ddsolve.scene.unstructured`): METIS
subdomains are not translates of each other, so no template detection is
attempted (``template = arange(n_sub)``, ``n_templates == n_subdomains``). The
broken mesh is built with two bulk calls (``AddPoints``, one ``AddElements``
for all triangles), assembled once on all subdomains, and the block diagonal is
cut into the per-subdomain matrices.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from .scene import Scene

log = logging.getLogger(__name__)


@dataclass
class LocalProblems:
    """Assembled local data of all subdomains.

    Attributes
    ----------
    scene : Scene
    nodes : list of ndarray of int
        Global node ids of each subdomain, in the canonical local order.
    template : ndarray of int, shape (n_subdomains,)
        Template id of each subdomain.
    stiffness : list of scipy.sparse.csr_matrix
        ``stiffness[t]``: unit-coefficient Q1 or P1 stiffness matrix of template t,
        shape (n_t, n_t), all local nodes (Dirichlet nodes included).
    loads : list of ndarray
        ``loads[s]``: local load vector f^(s) = int_{Omega_s} f phi_k, shape (n_s,).
    """

    scene: Scene
    nodes: list[np.ndarray]
    template: np.ndarray
    stiffness: list[sp.csr_matrix]
    loads: list[np.ndarray]

    @property
    def n_templates(self) -> int:
        return len(self.stiffness)


def detect_templates(scene: Scene, nodes: list[np.ndarray]) -> np.ndarray:
    """Group subdomains that are translates of each other.

    Two subdomains share a template when their node coordinates relative to
    the lower-left corner agree to 1e-10 of the scene size and their elements
    have the same local connectivity.

    Returns
    -------
    ndarray of int, shape (n_subdomains,)
    """
    size = float(np.ptp(scene.coords, axis=0).max()) or 1.0
    order = np.argsort(scene.element_subdomain, kind="stable")
    bounds = np.searchsorted(scene.element_subdomain[order], np.arange(scene.n_subdomains + 1))
    keys: dict[bytes, int] = {}
    template = np.empty(scene.n_subdomains, dtype=np.int64)
    for s, nd in enumerate(nodes):
        rel = np.round((scene.coords[nd] - scene.coords[nd].min(axis=0)) / size, 10)
        local = _local_connectivity(nd, scene.elements[order[bounds[s]:bounds[s + 1]]])
        local = local[np.lexsort(local.T[::-1])]
        key = rel.tobytes() + b"|" + local.tobytes()
        template[s] = keys.setdefault(key, len(keys))
    return template


def _local_connectivity(nodes: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Element connectivity in local node indices (``nodes`` is the local order)."""
    srt = np.argsort(nodes)
    return srt[np.searchsorted(nodes[srt], elements)]


def _coefficient(f: Any, ngs: Any, element_values_cf: Any = None) -> Any:
    if callable(f):
        return f(ngs.x, ngs.y)
    return ngs.CoefficientFunction(float(f))


def assemble(scene: Scene) -> LocalProblems:
    """Assemble local stiffness matrices (per template) and load vectors with NGSolve.

    Parameters
    ----------
    scene : Scene
        ``scene.f`` is a number, or a callable ``f(x, y)`` that receives
        NGSolve's coordinate functions and returns a CoefficientFunction (so it
        may use ``ngsolve.IfPos`` etc.), or an ndarray of shape (n_elements,)
        of element-wise constant loads.

    Returns
    -------
    LocalProblems
    """
    import ngsolve as ngs
    from netgen.meshing import Mesh as NGMesh

    if scene.element_type == "P1":
        return _assemble_p1(scene)
    nodes = scene.subdomain_nodes()
    template = detect_templates(scene, nodes)
    n_sub = scene.n_subdomains
    offsets = np.concatenate([[0], np.cumsum([len(nd) for nd in nodes])])

    order = np.argsort(scene.element_subdomain, kind="stable")
    bounds = np.searchsorted(scene.element_subdomain[order], np.arange(n_sub + 1))

    ngmesh = NGMesh(dim=2)
    points = np.concatenate([scene.coords[nd] for nd in nodes])
    ngmesh.AddPoints(np.ascontiguousarray(np.column_stack([points, np.zeros(len(points))])))
    for s in range(n_sub):
        region = ngmesh.AddRegion(f"s{s}", 2)
        local = _local_connectivity(nodes[s], scene.elements[order[bounds[s]:bounds[s + 1]]])
        ngmesh.AddElements(dim=2, index=region, data=np.ascontiguousarray(local + offsets[s], dtype=np.int32),
                           base=0)
    mesh = ngs.Mesh(ngmesh)
    fes = ngs.H1(mesh, order=1)
    u, v = fes.TnT()

    # Stiffness: only on one representative subdomain per template.
    reps = np.array([int(np.flatnonzero(template == t)[0]) for t in range(template.max() + 1)])
    rep_region = mesh.Materials("|".join(f"s{s}" for s in reps))
    a = ngs.BilinearForm(fes)
    a += ngs.grad(u) * ngs.grad(v) * ngs.dx(definedon=rep_region)
    a.Assemble()
    rows, cols, vals = a.mat.COO()
    A = sp.csr_matrix((np.asarray(vals), (np.asarray(rows), np.asarray(cols))), shape=(fes.ndof, fes.ndof))
    stiffness = []
    for s in reps:
        block = A[offsets[s]:offsets[s + 1], offsets[s]:offsets[s + 1]].tocsr()
        block.sum_duplicates()
        block.eliminate_zeros()
        stiffness.append(block)

    loads = _loads(scene, mesh, fes, order, offsets)
    log.info("assembled %d subdomains with %d templates (%d broken dofs)", n_sub, len(reps), fes.ndof)
    return LocalProblems(scene=scene, nodes=nodes, template=template, stiffness=stiffness, loads=loads)


def _loads(scene: Scene, mesh: Any, fes: Any, order: np.ndarray, offsets: np.ndarray) -> list[np.ndarray]:
    """Local loads f^(s)_k = int_{Omega_s} f phi_k of every subdomain on the broken mesh.

    ``order[k]`` is the scene element of broken-mesh element k.
    """
    import ngsolve as ngs

    n_sub = scene.n_subdomains
    v = fes.TestFunction()
    if isinstance(scene.f, np.ndarray):
        l2 = ngs.L2(mesh, order=0)
        gf = ngs.GridFunction(l2)
        # broken-mesh element k corresponds to scene element order[k]
        gf.vec.FV().NumPy()[:] = np.asarray(scene.f, dtype=float)[order]
        fcf = gf
    else:
        fcf = _coefficient(scene.f, ngs)
    lf = ngs.LinearForm(fes)
    lf += fcf * v * ngs.dx
    lf.Assemble()
    fvec = np.array(lf.vec.FV().NumPy(), copy=True)
    return [fvec[offsets[s]:offsets[s + 1]] for s in range(n_sub)]


def _assemble_p1(scene: Scene) -> LocalProblems:
    """P1 assembly: one broken NGSolve mesh, one assembly, blocks cut per subdomain.

    Every subdomain is its own template (``stiffness[s]`` is the
    unit-coefficient matrix of subdomain s). Two bulk netgen calls build the
    mesh; there is no Python loop over elements.
    """
    import ngsolve as ngs
    from netgen.meshing import Mesh as NGMesh

    nodes = scene.subdomain_nodes()
    n_sub = scene.n_subdomains
    sizes = np.array([len(nd) for nd in nodes], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    node_all = np.concatenate(nodes)
    sub_all = np.repeat(np.arange(n_sub, dtype=np.int64), sizes)
    # broken id of (subdomain, node): sort the (subdomain, node) keys once
    key = sub_all * scene.n_nodes + node_all
    srt = np.argsort(key)
    order = np.argsort(scene.element_subdomain, kind="stable")
    els = np.asarray(scene.elements, dtype=np.int64)[order]
    el_key = np.asarray(scene.element_subdomain, dtype=np.int64)[order][:, None] * scene.n_nodes + els
    broken = srt[np.searchsorted(key[srt], el_key)]

    ngmesh = NGMesh(dim=2)
    ngmesh.AddPoints(np.ascontiguousarray(np.column_stack([scene.coords[node_all], np.zeros(len(node_all))])))
    region = ngmesh.AddRegion("omega", 2)
    ngmesh.AddElements(dim=2, index=region, data=np.ascontiguousarray(broken, dtype=np.int32), base=0)
    mesh = ngs.Mesh(ngmesh)
    fes = ngs.H1(mesh, order=1)
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    a += ngs.grad(u) * ngs.grad(v) * ngs.dx
    a.Assemble()
    rows, cols, vals = a.mat.COO()
    A = sp.csr_matrix((np.asarray(vals), (np.asarray(rows), np.asarray(cols))), shape=(fes.ndof, fes.ndof))
    A.sum_duplicates()
    stiffness = [_diagonal_block(A, offsets[s], offsets[s + 1]) for s in range(n_sub)]
    loads = _loads(scene, mesh, fes, order, offsets)
    log.info("assembled %d P1 subdomains (%d broken dofs)", n_sub, fes.ndof)
    return LocalProblems(scene=scene, nodes=nodes, template=np.arange(n_sub), stiffness=stiffness, loads=loads)


def _diagonal_block(A: sp.csr_matrix, lo: int, hi: int) -> sp.csr_matrix:
    """Rows and columns lo:hi of a block-diagonal CSR matrix (its rows have no entries outside)."""
    start, stop = A.indptr[lo], A.indptr[hi]
    block = sp.csr_matrix((A.data[start:stop], A.indices[start:stop] - lo, A.indptr[lo:hi + 1] - start),
                          shape=(hi - lo, hi - lo))
    block.eliminate_zeros()
    return block
