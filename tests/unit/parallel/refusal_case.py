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
         "one": dict(problem="poisson", method="fetidp", subdomains=1)}

if __name__ == "__main__":
    rank = MPI.COMM_WORLD.rank
    for name in sys.argv[1:]:
        try:
            solve(SPECS[name])
            print(f"{name} {rank} solved", flush=True)
        except InputError as exc:
            print(f"{name} {rank} {exc.field}", flush=True)
