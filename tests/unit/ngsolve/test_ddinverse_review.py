"""Regressions from the black-box review of DDInverse (bad input must be one clear InputError)."""
from __future__ import annotations

import pytest

ngs = pytest.importorskip("ngsolve")
from netgen.geom2d import unit_square

import ddsolve.dd.local as local
from ddsolve.errors import InputError
from ddsolve.ngsolve import DDInverse


@pytest.fixture(scope="module")
def mesh():
    return ngs.Mesh(unit_square.GenerateMesh(maxh=0.1))


@pytest.mark.parametrize("method", ["bddc", "fetidp", "feti"])
@pytest.mark.parametrize("backend", ["dense", "pardiso"])
@pytest.mark.parametrize("reaction", [-400.0, None])   # Helmholtz k = 20; None: the negative Laplacian
def test_indefinite_form_is_an_input_error(mesh, method, backend, reaction, monkeypatch):
    """A subdomain matrix that is not SPD (dense Cholesky or PARDISO fails) names ``a``, no LinAlgError."""
    from ddsolve.dd import pardiso

    if backend == "pardiso":
        if not pardiso.available():
            pytest.skip("MKL PARDISO not available")
        monkeypatch.setattr(local, "DENSE_LIMIT", 10)
        monkeypatch.setattr(local, "SPARSE_BACKEND", "pardiso")
    fes = ngs.H1(mesh, order=2, dirichlet=".*")
    u, v = fes.TnT()
    a = ngs.BilinearForm(fes)
    if reaction is None:
        a += -ngs.grad(u) * ngs.grad(v) * ngs.dx
    else:
        a += ngs.grad(u) * ngs.grad(v) * ngs.dx + reaction * u * v * ngs.dx
    with pytest.raises(InputError, match=r"^a: a subdomain matrix is not positive definite"):
        DDInverse(a, method=method, parts=2)


def test_vector_of_wrong_size_is_an_input_error(mesh):
    """Mult, the preconditioner and solve() name the vector whose size is wrong (was a numpy broadcast error)."""
    import numpy as np

    fes = ngs.H1(mesh, order=2, dirichlet=".*")
    u, v = fes.TnT()
    inv = DDInverse(ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx), parts=4)
    n = fes.ndof
    good, short, long = ngs.BaseVector(n), ngs.BaseVector(n - 1), ngs.BaseVector(n + 5)
    for vec in (good, short, long):
        vec[:] = 1.0
    for op in (inv, inv.preconditioner):
        with pytest.raises(InputError, match=rf"^f: expected a vector of {n} entries .*got shape \({n - 1},\)"):
            good.data = op * short
        with pytest.raises(InputError, match=rf"^result: expected a vector of {n} entries .*got shape \({n + 5},\)"):
            long.data = op * good
    with pytest.raises(InputError, match=rf"^f: expected a vector of {n} entries"):
        inv.solve(np.ones(n + 1))
    good.data = inv * good                      # the right size still works
    assert inv.converged and np.isfinite(good.FV().NumPy()).all()


def test_fes_with_other_dofs_than_the_form_is_an_input_error(mesh):
    """fes of another order than a.space was accepted and gave an operator of the wrong size."""
    import numpy as np

    fes2 = ngs.H1(mesh, order=2, dirichlet=".*")
    u, v = fes2.TnT()
    form = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx)
    with pytest.raises(InputError, match=r"^fes: has \d+ dofs but the form's space has"):
        DDInverse(form, fes=ngs.H1(mesh, order=1, dirichlet=".*"))
    # same dofs, other Dirichlet boundaries: fes.FreeDofs() is used
    other = ngs.H1(mesh, order=2, dirichlet="left")
    inv = DDInverse(form, fes=other, parts=4, rtol=1e-10)
    f = ngs.LinearForm(other)
    f += v * ngs.dx
    f.Assemble()
    form.Assemble()
    ref = (form.mat.Inverse(other.FreeDofs(), inverse="sparsecholesky") * f.vec).Evaluate()
    u_dd = (inv * f.vec).Evaluate()
    r, d = ref.FV().NumPy(), u_dd.FV().NumPy()
    assert np.linalg.norm(d - r) <= 1e-8 * np.linalg.norm(r)


def test_a_complex_right_hand_side_is_named_f(mesh):
    """inv * b with a complex b named "y", NGSolve's (complex) result vector the user never wrote (a review)."""
    fes = ngs.H1(mesh, order=1, dirichlet=".*")
    u, v = fes.TnT()
    inv = DDInverse(ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx), parts=4)
    b = ngs.BaseVector(fes.ndof, True)
    b[:] = 1.0 + 1.0j
    for op in (inv, inv.preconditioner):
        with pytest.raises(InputError, match=r"^f: complex vectors are not supported"):
            (op * b).Evaluate()


@pytest.mark.parametrize("partition", ["materials", "array"])
def test_parts_with_a_partition_that_gives_the_parts_is_refused(mesh, partition):
    """parts=5 with an array of 3 labels was ignored silently (a review): the partition gives the parts there.
    parts is refused with "materials" and an array, and still counts METIS parts with "coarse" and None."""
    import numpy as np

    fes = ngs.H1(mesh, order=1, dirichlet=".*")
    u, v = fes.TnT()
    a = ngs.BilinearForm(ngs.grad(u) * ngs.grad(v) * ngs.dx)
    given = "materials" if partition == "materials" else np.arange(mesh.ne) % 3
    with pytest.raises(InputError, match=r"^parts: is given by partition="):
        DDInverse(a, parts=5, partition=given)
    assert DDInverse(a, partition=given).n_parts >= (1 if partition == "materials" else 3)
    assert DDInverse(a, parts=5).n_parts == 5 and DDInverse(a).n_parts == 16
    with pytest.raises(InputError, match=r"^partition: expected None, 'materials', 'coarse' or an array"):
        DDInverse(a, parts=5, partition="metis")           # the mistyped name is the error, not parts
