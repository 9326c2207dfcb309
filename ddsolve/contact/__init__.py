"""Contact problem (3.1): the active set method with the hybrid method (Chapter 5), SMALBE/MPRGP on
the FETI-DP dual (Chapter 6) and a primal-dual active set reference with sparse direct solves."""
from .active_set import ActiveSetHybrid, solve_contact_active_set
from .direct import ContactSolution, solve_contact_direct
from .problem import ContactProblem, KKTResiduals
from .smalbe_dual import solve_contact_smalbe

__all__ = ["ContactProblem", "KKTResiduals", "ContactSolution", "ActiveSetHybrid",
           "solve_contact_active_set", "solve_contact_direct", "solve_contact_smalbe"]
