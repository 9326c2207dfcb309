"""Contact problem (3.1): the active set method with the hybrid method (Chapter 5), SMALBE/MPRGP on
the FETI-DP dual (Chapter 6) and a primal-dual active set reference with sparse direct solves."""
from .problem import ContactProblem, KKTResiduals

__all__ = ["ContactProblem", "KKTResiduals"]
