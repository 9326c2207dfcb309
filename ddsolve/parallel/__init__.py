"""Subdomain-parallel FETI-DP and BDDC over MPI (mpi4py); see docs/parallel.md.

Nothing here imports mpi4py at import time: serial runs never load it.
"""
from .run import METHODS, check_supported, mpi_world_size, solve

__all__ = ["METHODS", "check_supported", "mpi_world_size", "solve"]
