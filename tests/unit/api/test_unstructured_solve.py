"""Every method on unstructured (netgen P1, METIS) scenes through ``ddsolve.solve``, checked against direct solves.

poisson and multibody: the relative energy error against the direct solve of the
same discrete problem (``check=True``) is < 1e-8 at rtol 1e-10. contact: the
energy and the active set agree with the primal-dual active set method
(``method="direct"``) on the same mesh and partition, and the KKT residual is
<= 1e-8.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ddsolve import solve
from ddsolve.spec import ProblemSpec

MESH = dict(mesh="unstructured", maxh=0.15, parts=5)


@pytest.mark.parametrize("method", ["feti", "fetidp", "bddc"])
@pytest.mark.parametrize("geometry", ["square", "lshape", "hole"])
def test_poisson_methods_match_direct(method, geometry):
    result = solve(ProblemSpec(problem="poisson", method=method, geometry=geometry, rtol=1e-10, check=True,
                               rho="checkerboard:10", **MESH))
    assert result.converged, result.reason
    assert result.error_vs_direct is not None and result.error_vs_direct < 1e-8
    assert (result.subdomains, result.elements) == (5, 0)
    assert result.extra["mesh"] == "unstructured" and result.extra["parts"] == 5
    if geometry != "hole":     # the parts of the annulus may meet in pairs only: no cross points there
        assert result.extra["n_primal"] > 0


@pytest.mark.parametrize("method", ["feti-feti", "hybrid"])
def test_multibody_methods_match_direct(method):
    result = solve(ProblemSpec(problem="multibody", method=method, bodies=2, rtol=1e-10, check=True,
                               rho="body-checkerboard:100", **MESH))
    assert result.converged, result.reason
    assert result.error_vs_direct is not None and result.error_vs_direct < 1e-8


@pytest.fixture(scope="module")
def contact_direct():
    return solve(ProblemSpec(problem="contact", method="direct", **MESH))


@pytest.mark.parametrize("method", ["active-set", "smalbe"])
def test_contact_methods_match_direct(method, contact_direct):
    result = solve(ProblemSpec(problem="contact", method=method, rtol=1e-10, check=True, **MESH))
    ref = contact_direct.extra
    assert result.converged, result.reason
    assert result.extra["kkt_residual"] <= 1e-8
    assert ref["kkt_residual"] <= 1e-8
    assert result.extra["n_active"] == ref["n_active"] > 0
    assert abs(result.extra["energy"] - ref["energy"]) <= 1e-8 * abs(ref["energy"])
    assert result.error_vs_direct < 1e-6


def test_json_keys_and_timings():
    result = solve(ProblemSpec(problem="poisson", method="fetidp", **MESH))
    summary = json.loads(json.dumps(result.to_dict()))
    assert set(summary["timings"]) == {"mesh", "partition", "assembly", "setup", "solve"}
    assert all(isinstance(v, float) and v >= 0 and math.isfinite(v) for v in summary["timings"].values())
    assert summary["timings"]["mesh"] > 0 and summary["peak_rss_mb"] > 50
    assert summary["mesh"] == "unstructured" and summary["parts"] == 5 and summary["n_primal"] > 0
    structured = solve(ProblemSpec()).to_dict()
    assert structured["mesh"] == "structured" and structured["parts"] == 4
    assert (structured["subdomains"], structured["elements"]) == (2, 4)
    assert structured["timings"]["partition"] == 0.0


def test_refine_quadruples_triangles():
    from ddsolve.prepared import prepare

    coarse = prepare(ProblemSpec(**MESH)).scene
    fine = prepare(ProblemSpec(refine=1, **MESH)).scene
    assert fine.elements.shape[0] == 4 * coarse.elements.shape[0]
    assert np.unique(fine.element_subdomain).size == 5


def test_checkerboard_is_part_parity():
    from ddsolve.prepared import prepare

    prep = prepare(ProblemSpec(rho="checkerboard:7", **MESH))
    part = np.arange(prep.scene.n_subdomains) % 5
    np.testing.assert_array_equal(prep.scene.rho, np.where(part % 2 == 1, 7.0, 1.0))
