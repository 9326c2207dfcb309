"""The API layer: one registry per problem, one immutable result, one prepare path."""
from __future__ import annotations

import dataclasses

import pytest

import ddsolve
from ddsolve.api import SOLVERS
from ddsolve.options import METHODS
from ddsolve.spec import ProblemSpec


def test_registry_covers_every_method_of_every_problem():
    assert {p: tuple(SOLVERS[p]) for p in SOLVERS} == {p: tuple(ms) for p, ms in METHODS.items()}


def test_result_is_immutable_and_matches_prepare():
    spec = ProblemSpec(method="fetidp", subdomains=2, elements=4)
    result = ddsolve.solve(spec)
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.converged = False  # type: ignore[misc]
    prep = ddsolve.prepare(spec)
    assert result.ndof == prep.sub.ndof == 49
    assert set(prep.timings) == {"scene", "assembly", "substructures"}
    assert result.extra["restarts"] == 0


def test_prepare_builds_the_contact_problem_once():
    prep = ddsolve.prepare(ProblemSpec(problem="contact", subdomains=2, elements=4))
    assert prep.contact is not None and prep.contact.n_contact == 9
    assert "contact" in prep.timings
    res = ddsolve.solve(prep.spec)
    assert res.converged and res.extra["n_contact"] == 9
    assert res.extra["kkt_residual"] < 1e-5   # the active set method at its default rtol 1e-5
    assert res.extra["n_active"] == 7
