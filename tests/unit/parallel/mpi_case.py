"""Run under mpiexec by test_mpi.py: one distributed solve, rank 0 writes an npz.

Usage: mpi_case.py METHOD {structured,unstructured,middle} OUT.npz
"""
import sys

import numpy as np

from ddsolve.parallel import solve


def case(method: str, kind: str):
    """The spec and scene (None: the spec's structured scene) of a test case; shared with the serial side."""
    if method in ("feti-feti", "hybrid"):       # multibody (4.32): 3 x 3 bodies, the middle one floats
        spec = dict(problem="multibody", method=method, bodies=3, subdomains=2, elements=4,
                    rho="checkerboard:100", f="random:2", cond=True, contact="full")
        if kind == "middle":
            return {**spec, "contact": "middle"}, None
        if kind == "structured":
            return spec, None
        from ddsolve.scene import unstructured_scene
        scene = unstructured_scene("multibody", maxh=0.12, parts=3, bodies=3, rho=np.geomspace(1.0, 1e3, 27),
                                   seed=0)
        scene.f = np.random.default_rng(3).uniform(-1.0, 1.0, scene.elements.shape[0])
        return dict(problem="multibody", method=method, cond=True, contact="full"), scene
    if method == "active-set":           # contact (3.1): two membranes, Omega^2 floats
        if kind == "structured":
            return dict(problem="contact", method=method, subdomains=3, elements=4), None
        from ddsolve.scene import unstructured_scene
        scene = unstructured_scene("contact", maxh=0.1, parts=3, seed=0)
        return dict(problem="contact", method=method, mesh="unstructured", parts=3, maxh=0.1), scene
    if kind == "structured":
        return dict(method=method, subdomains=4, elements=5, rho="checkerboard:100", f="random:1", cond=True), None
    from ddsolve.scene import unstructured_scene
    scene = unstructured_scene("poisson", maxh=0.06, parts=7, rho=np.geomspace(1.0, 1e3, 7), seed=0)
    return dict(method=method, cond=True), scene


if __name__ == "__main__":
    method, kind, out = sys.argv[1:4]
    spec, scene = case(method, kind)
    try:
        result = solve(spec, scene=scene)
    except Exception:                   # noqa: BLE001 - one failing rank ends the job (no hang until the timeout)
        import traceback

        from mpi4py import MPI
        traceback.print_exc()
        MPI.COMM_WORLD.Abort(1)
    if result is not None and method == "active-set":
        e = result.extra
        np.savez(out, u=result.u, n_ranks=e["n_ranks"], messages=e["comm"]["messages_per_iteration"],
                 outer=e["outer_iterations"], inner=np.asarray(e["inner_iterations"]), pcg=e["pcg_iterations"],
                 n_active=e["n_active"], kkt=e["kkt_residual"], converged=result.converged)
    elif result is not None:
        np.savez(out, u=result.u, iterations=result.iterations, cond=np.nan if result.cond is None else result.cond,
                 n_ranks=result.extra["n_ranks"], messages=result.extra["comm"]["messages_per_iteration"],
                 error_estimate=result.extra.get("error_estimate", np.nan))
