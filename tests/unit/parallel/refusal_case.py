"""Run under mpiexec by test_library_refusals_mpi.py: ddsolve.parallel.solve on specs the command line
refuses under mpiexec; every rank prints one line per spec, ``<name> <rank> <field>`` for an InputError."""
import sys

from mpi4py import MPI

from ddsolve.errors import InputError
from ddsolve.parallel import solve

SPECS = {"direct": dict(problem="poisson", method="direct"),
         "smalbe": dict(problem="contact", method="smalbe"),
         "edges": dict(problem="poisson", method="fetidp", primal="vertices+edges", subdomains=3),
         "lumped": dict(problem="multibody", method="hybrid", bodies=2, projection="lumped"),
         "one": dict(problem="poisson", method="fetidp", subdomains=1),
         "scene": dict(problem="poisson", method="bddc", subdomains=1)}

if __name__ == "__main__":
    rank = MPI.COMM_WORLD.rank
    lines = []
    for name in sys.argv[1:]:
        scene = None
        if name == "scene":          # a caller's scene: its parts decide, not the spec's subdomains (here 1)
            from ddsolve.scene import unstructured_scene
            scene = unstructured_scene("poisson", maxh=0.3, parts=2, rho=1.0, seed=0)
        try:
            result = solve(SPECS[name], scene=scene)
            lines.append(f"{name} {rank} solved" + (f" {result.converged}" if rank == 0 else ""))
        except InputError as exc:
            lines.append(f"{name} {rank} {exc.field}")
    # rank 0 prints every rank's lines: two ranks printing at once interleaved their lines on the shared
    # stdout (an empty line and a joined one, once in a CI run)
    every = MPI.COMM_WORLD.gather(lines)
    if rank == 0:
        print("\n".join(line for part in every for line in part), flush=True)
