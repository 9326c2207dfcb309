"""Shared fixtures and helpers for the ddsolve test suite."""
from __future__ import annotations

import numpy as np
import pytest

from ddsolve.api import build_scene
from ddsolve.dd import Substructures
from ddsolve.scene import assemble
from ddsolve.spec import ProblemSpec


def substructures(**fields) -> Substructures:
    """Assembled Substructures of a structured Poisson spec (fields of ProblemSpec)."""
    spec = ProblemSpec.from_mapping(fields)
    return Substructures(assemble(build_scene(spec)), scaling=spec.scaling, gamma=spec.gamma)


def dense(op, n: int) -> np.ndarray:
    """Columns op(e_k): only for exact spectra of tiny test cases."""
    eye = np.eye(n)
    return np.column_stack([op(eye[:, k]) for k in range(n)])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20091)
