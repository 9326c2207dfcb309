"""Substructuring solvers on one body: one-level FETI, FETI-DP, BDDC, direct."""
from .bddc import solve_bddc
from .common import MethodOutput
from .direct import solve_direct
from .feti import solve_feti
from .fetidp import solve_fetidp
from .substructure import Substructures

__all__ = ["Substructures", "MethodOutput", "solve_feti", "solve_fetidp", "solve_bddc", "solve_direct"]
