"""The one definition of the contact result fields (serial and MPI): ``contact_fields`` of ``ContactMeasures``."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ddsolve.api import SOLVERS
from ddsolve.contact.problem import KKTResiduals
from ddsolve.contact.run import ContactMeasures, contact_fields, contact_result_fields
from ddsolve.prepared import prepare
from ddsolve.spec import ProblemSpec

SPEC = dict(problem="contact", method="active-set", subdomains=2, elements=4)


@pytest.fixture(scope="module")
def solved():
    prep = prepare(SPEC)
    return prep, SOLVERS["contact"]["active-set"](prep)


def test_serial_fields_are_contact_fields_of_the_assembled_measures(solved):
    prep, sol = solved
    spec = ProblemSpec.from_mapping(SPEC)
    fields = contact_result_fields(spec, prep.contact, sol)
    measures = ContactMeasures.of(prep.contact, sol.u, sol.lam)
    again = contact_fields(spec, sol, measures)
    assert fields["extra"] == again["extra"] and fields["converged"] and again["converged"]
    assert fields["extra"]["energy"] == prep.contact.energy(sol.u) < 0.0
    assert fields["extra"]["n_contact"] == prep.contact.n_contact == 9
    assert {k: v for k, v in fields.items() if k not in ("u", "extra")} == \
        {k: v for k, v in again.items() if k not in ("u", "extra")}


@pytest.mark.parametrize("stationarity", [1e-2, math.inf, math.nan])
def test_acceptance_test_reads_the_given_kkt(solved, stationarity):
    """A large, infinite or NaN KKT residual, however computed, is not accepted (the MPI path uses this too);
    NaN in the last part used to vanish in the builtin max()."""
    prep, sol = solved
    spec = ProblemSpec.from_mapping(SPEC)
    good = ContactMeasures.of(prep.contact, sol.u, sol.lam)
    bad = replace(good, kkt=replace(good.kkt, stationarity=stationarity))
    fields = contact_fields(spec, sol, bad)
    assert not fields["converged"] and fields["reason"].startswith("not accepted: ")
    assert np.array_equal([fields["extra"]["kkt_stationarity"], fields["extra"]["kkt_residual"]],
                          [stationarity, stationarity], equal_nan=True)
    assert isinstance(good.kkt, KKTResiduals) and np.isfinite(good.kkt.max) and good.kkt.max < 1e-3
