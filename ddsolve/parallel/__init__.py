"""Subdomain-parallel solves over MPI (mpi4py): FETI-DP, BDDC, FETI, FETI-FETI, the hybrid and the
active set method (:data:`~ddsolve.parallel.run.DISTRIBUTED`); see docs/parallel.md.

Nothing here imports mpi4py at import time: serial runs never load it.
"""
from .run import DISTRIBUTED, METHODS, check_supported, mpi_world_size, solve

__all__ = ["DISTRIBUTED", "METHODS", "check_supported", "mpi_world_size", "solve"]
