"""Explicit local Schur complements of many batched subdomains (a general mesh), built column window by
column window: a window costs its width in solves of the whole block-diagonal factorization, however many
subdomains it holds (batches of subdomains paid those solves once per batch: 587 s at 1M dofs)."""
from __future__ import annotations

import math

import numpy as np

import ddsolve.dd.operators as operators
from ddsolve import ProblemSpec, prepare
from ddsolve.dd.local import _BlockView
from ddsolve.dd.operators import DirichletSchur


def _sub():
    return prepare(ProblemSpec(method="bddc", mesh="unstructured", geometry="square", maxh=0.02, parts=24)).sub


def _counted_whole_solves(schur):
    """Wrap the one batched factorization's solve; return the list its calls append their widths to."""
    views = {id(v.factor): v.factor for v in schur._cache.values() if isinstance(v, _BlockView)}
    assert len(views) == 1                         # the interior K_II of all subdomains: one factorization
    whole = next(iter(views.values()))
    assert whole.kind == "sparse" and whole._blocks.size - 1 == 24
    calls: list[int] = []
    solve = whole.solve

    def counted(B):
        calls.append(1 if B.ndim == 1 else B.shape[1])
        return solve(B)

    whole.solve = counted
    return calls


def test_windowed_build_equals_the_whole_one_and_costs_its_columns(monkeypatch):
    sub = _sub()
    reference = DirichletSchur(sub, sub.interface, {}, explicit=True)
    whole_calls = _counted_whole_solves(reference)
    ref_blocks = reference.explicit_blocks()
    widest = max(int(np.count_nonzero(sub.interface[sub.offsets[s]:sub.offsets[s + 1]])) for s in range(sub.n_sub))
    assert sum(whole_calls) == widest                  # every column of the widest interface, once
    assert reference.extensions is not None

    window = 3
    rows = int(np.count_nonzero(~sub.interface))       # the interior entries (no Dirichlet nodes held out here)
    monkeypatch.setattr(operators, "EXPLICIT_EXTENSION_BYTES", 0)           # extensions not kept
    monkeypatch.setattr(operators, "EXPLICIT_BUILD_BYTES", 8 * rows * window)
    windowed = DirichletSchur(sub, sub.interface, {}, explicit=True)
    calls = _counted_whole_solves(windowed)
    blocks = windowed.explicit_blocks()
    assert windowed.extensions is None
    assert len(calls) == math.ceil(widest / window) and sum(calls) == widest
    xs = np.random.default_rng(0).standard_normal(ref_blocks.size)
    expected = ref_blocks.apply(xs)
    np.testing.assert_allclose(blocks.apply(xs), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_one_column_windows_on_shared_templates_and_a_forced_build(monkeypatch):
    """Structured subdomains share templates (one factorization each, no batched one) and a Dirichlet
    exclude leaves groups of different interiors; one-column windows of a forced build (the rent-or-buy
    switch: extensions not kept) give the blocks of the one-window build."""
    sub = prepare(ProblemSpec(method="bddc", subdomains=4, elements=6)).sub
    exclude = np.zeros(sub.n_W, dtype=bool)
    exclude[np.flatnonzero(~sub.interface)[::7]] = True          # some interior entries held out
    reference = DirichletSchur(sub, sub.interface, {}, exclude=exclude, explicit=True).explicit_blocks()
    monkeypatch.setattr(operators, "EXPLICIT_BUILD_BYTES", 1)    # windows of one column
    windowed = DirichletSchur(sub, sub.interface, {}, exclude=exclude, explicit=False)
    assert not windowed.explicit
    blocks = windowed._build_explicit(force=True)
    assert windowed._extensions is None
    xs = np.random.default_rng(1).standard_normal(reference.size)
    expected = reference.apply(xs)
    np.testing.assert_allclose(blocks.apply(xs), expected, rtol=0, atol=1e-12 * np.abs(expected).max())
