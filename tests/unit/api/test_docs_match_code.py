"""The docs name what the code does: every CLI flag in docs/cli.md, every preset option in docs/methods.md."""
from __future__ import annotations

from conftest import ROOT

from ddsolve.cli import build_parser
from ddsolve.options import PRESETS
from ddsolve.presets import THESIS_OPTIONS


def _solve_flags() -> list[str]:
    solve = build_parser()._subparsers._group_actions[0].choices["solve"]
    return [o for action in solve._actions for o in action.option_strings if o.startswith("--") and o != "--help"]


def test_every_cli_flag_is_documented():
    doc = (ROOT / "docs" / "cli.md").read_text()
    missing = [flag for flag in _solve_flags() if f"`{flag}" not in doc]
    assert not missing, f"flags of `ddsolve solve` missing from docs/cli.md: {missing}"


def test_every_thesis_preset_option_is_documented():
    doc = (ROOT / "docs" / "methods.md").read_text()
    assert "The thesis preset" in doc and all(f"`{p}`" in doc or p in doc for p in PRESETS)
    missing = [(key, option) for key, options in THESIS_OPTIONS.items() for option in options if option not in doc]
    assert not missing, f"preset options missing from docs/methods.md: {missing}"
