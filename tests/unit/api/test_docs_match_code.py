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


def _anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    import re

    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_link_between_the_docs_resolves():
    """docs/studies.md linked findings.md#tables-41-and-42, a heading that does not exist (a review): every
    relative link of README.md and docs/*.md must name an existing file and, in a Markdown file, a heading
    or an HTML id of it."""
    import re

    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    anchors = {}
    for path in files:
        text = path.read_text()
        prose = re.sub(r"```.*?```", "", text, flags=re.S)
        anchors[path.resolve()] = ({_anchor(h) for h in re.findall(r"^#+ (.*)$", prose, re.M)}
                                   | set(re.findall(r'(?:id|name)="([^"]+)"', text)))
    broken = []
    for path in files:
        for target in re.findall(r"\]\(([^)\s]+)\)", path.read_text()):
            if target.startswith(("http://", "https://", "mailto:")):
                continue
            file_part, _, fragment = target.partition("#")
            linked = (path.parent / file_part).resolve() if file_part else path.resolve()
            if not linked.exists():
                broken.append(f"{path.name}: {target} (no such file)")
            elif fragment and linked.suffix == ".md" and fragment not in anchors.get(linked, set()):
                broken.append(f"{path.name}: {target} (no such heading)")
    assert not broken, broken
    assert sum(len(a) for a in anchors.values()) > 50           # the headings were read
