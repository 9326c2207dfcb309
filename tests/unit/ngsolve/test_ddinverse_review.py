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
