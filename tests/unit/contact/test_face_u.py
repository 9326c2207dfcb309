"""The active set method extends u_Gamma to all dofs once, for its last face solve (HybridSolver.solve
with interior=False for the faces): the discrete harmonic extension of every dof was made for every face
solve and thrown away: 0.03 s each at 1.04M dofs (16 x 16 subdomains per membrane, H/h 45), 5 of them in
the 6 face solves there, about 8% of the serial solve phase."""
from __future__ import annotations

import numpy as np

from ddsolve import ProblemSpec, prepare
from ddsolve.contact.active_set import solve_contact_active_set
from ddsolve.contact.direct import solve_contact_direct
from ddsolve.multibody.hybrid import HybridSolver


def test_one_extension_per_solve_and_the_same_answer(monkeypatch):
    contact = prepare(ProblemSpec(problem="contact", subdomains=2, elements=8)).contact
    calls = []
    extend = HybridSolver.extend

    def counted(self, u_gamma):
        calls.append(u_gamma.copy())
        return extend(self, u_gamma)

    monkeypatch.setattr(HybridSolver, "extend", counted)
    sol = solve_contact_active_set(contact, rtol=1e-8, pcg_rtol=1e-8)
    assert sol.converged and sol.outer_iterations >= 2, sol.reason
    assert len(calls) == 1
    ref = solve_contact_direct(contact)
    K = contact.K
    e = sol.u - ref.u
    assert np.sqrt(e @ (K @ e) / (ref.u @ (K @ ref.u))) < 1e-6
