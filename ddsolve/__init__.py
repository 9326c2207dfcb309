"""ddsolve: substructuring domain decomposition for multibody contact problems.

Implements the methods of J. Lee, *A Hybrid Domain Decomposition Method and its
Applications to Contact Problems* (NYU, 2009): PCG with Lanczos estimates, PCR,
one-level FETI, FETI-DP and BDDC (this release), with NGSolve assembly.

>>> from ddsolve import ProblemSpec, solve
>>> res = solve(ProblemSpec(method="fetidp", subdomains=4, elements=8, cond=True))
"""
import logging

from .errors import InputError, OutputError
from .result import SolveResult
from .spec import ProblemSpec

__version__ = "0.1.0"
logging.getLogger(__name__).addHandler(logging.NullHandler())


def solve(spec, *, max_memory=None):  # noqa: D103 - documented in ddsolve.api.solve
    from .api import solve as _solve
    return _solve(spec, max_memory=max_memory)


def prepare(spec, scene=None):  # noqa: D103 - documented in ddsolve.prepared.prepare
    from .prepared import prepare as _prepare
    return _prepare(spec, scene)


solve.__doc__ = "Solve a problem; see :func:`ddsolve.api.solve`."
prepare.__doc__ = "Assemble and decompose a problem; see :func:`ddsolve.prepared.prepare`."
__all__ = ["ProblemSpec", "SolveResult", "InputError", "OutputError", "solve", "prepare", "__version__"]
