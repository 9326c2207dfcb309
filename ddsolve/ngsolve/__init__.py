"""ddsolve for NGSolve users: substructuring inverses and preconditioners of a BilinearForm.

Inside this subpackage ``import ngsolve`` is the real NGSolve. Importing
``ddsolve.ngsolve`` imports NGSolve.
"""
from .contact import ContactResult, contact_solve
from .inverse import DDInverse, DDPreconditioner

__all__ = ["ContactResult", "DDInverse", "DDPreconditioner", "contact_solve"]
