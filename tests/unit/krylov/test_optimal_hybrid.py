"""HybridSolver.system gives PCR's system of solve(); the optimal count bounds PCR's from below."""
import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from ddsolve.dd import Substructures
from ddsolve.krylov import pcr
from ddsolve.krylov.optimal import minimal_residual_counts
from ddsolve.multibody import GlobalInterface
from ddsolve.multibody.hybrid import HybridSolver
from ddsolve.scene import assemble, structured_square


@pytest.mark.parametrize("nb,contact", [(2, "full"), (4, "middle")])
def test_system_reproduces_solve_and_bounds_pcr(nb, contact):
    scene = structured_square(nb, 2, 2, f=1.0)
    f = np.random.default_rng(0).uniform(-1, 1, scene.elements.shape[0])
    sub = Substructures(assemble(structured_square(nb, 2, 2, f=f)))
    gi = GlobalInterface(sub)
    active = gi.contact_mask(contact)
    with threadpool_limits(1, "blas"):
        hs = HybridSolver(sub, gi)
        out = hs.solve(active, rtol=1e-6, maxiter=500)
        A, M, b, x0 = hs.system(active)
        assert x0 is None
        kr = pcr(A, b, M=M, rtol=1e-6, maxiter=500)
        opt = minimal_residual_counts(A, b, M, rtol=1e-6, maxiter=200)
    assert kr.iterations == out.krylov.iterations
    np.testing.assert_allclose(kr.residuals[:5], out.krylov.residuals[:5], rtol=1e-10)
    assert opt.iterations is not None and opt.iterations <= kr.iterations
    # the exact minimum is never above PCR's residual at the same n
    m = min(opt.residuals.size, kr.residuals.size)
    assert np.all(opt.residuals[:m] <= kr.residuals[:m] * (1 + 1e-8))
    with pytest.raises(ValueError):
        hs.system(active, projection="oblique")
