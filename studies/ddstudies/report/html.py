"""HTML twins of the generated Markdown and CSV tables, for the Snakemake report.

The HTML report (``snakemake --report``) shows images, PDFs and HTML inline and offers every other
file for download only, so a table written as Markdown or CSV was a link there (a review). The
tables' rules therefore also write ``<name>.html`` from the same text with :func:`write_html`; the
Markdown stays the file the docs and readers use.

Only what the generated Markdown uses is converted: ``#`` headings, pipe tables (the alignment row
``|---|``), ``-``/``*`` bullet lists, paragraphs, `` `code` `` and ``**bold**``. Everything else is
text, HTML-escaped.
"""
from __future__ import annotations

import csv
import html
import io
import os
import re
from pathlib import Path

from ddsolve.io.hdf5 import atomic_target

__all__ = ["markdown_to_html", "csv_to_html", "write_html", "write_twins"]

_STYLE = ("body{font-family:sans-serif;font-size:14px;margin:1em}table{border-collapse:collapse;margin:.6em 0}"
          "th,td{border:1px solid #bbb;padding:2px 6px;text-align:right;white-space:nowrap}th{background:#eee}"
          "td:first-child,th:first-child{text-align:left}code{background:#f4f4f4}")
_RULE = re.compile(r"^\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*$")


def _inline(text: str) -> str:
    """Escaped text with `code` and **bold** marked up."""
    out = html.escape(text, quote=False)
    out = re.sub(r"`([^`]+)`", r"<code>\1</code>", out)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", out)


def _cells(line: str) -> list[str]:
    line = line.strip()
    if line.startswith("|"):
        line = line[1:]
    if line.endswith("|"):
        line = line[:-1]
    return [cell.strip() for cell in line.split("|")]


def _table(rows: list[list[str]], header: bool) -> str:
    parts = ["<table>"]
    for k, row in enumerate(rows):
        tag = "th" if header and k == 0 else "td"
        parts.append("<tr>" + "".join(f"<{tag}>{_inline(c)}</{tag}>" for c in row) + "</tr>")
    parts.append("</table>")
    return "\n".join(parts)


def markdown_to_html(text: str, title: str = "") -> str:
    """A standalone HTML page of the Markdown ``text`` (the subset above)."""
    lines = text.splitlines()
    body: list[str] = []
    paragraph: list[str] = []
    items: list[str] = []

    def flush() -> None:
        if paragraph:
            body.append("<p>" + _inline(" ".join(paragraph)) + "</p>")
            paragraph.clear()
        if items:
            body.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
            items.clear()

    i = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        if stripped.startswith("|") and i + 1 < len(lines) and _RULE.match(lines[i + 1].strip()):
            flush()
            rows = [_cells(line)]
            i += 2
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append(_cells(lines[i]))
                i += 1
            body.append(_table(rows, header=True))
            continue
        heading = re.match(r"^(#{1,6})\s+(.*)$", stripped)
        if heading:
            flush()
            level = len(heading.group(1))
            body.append(f"<h{level}>{_inline(heading.group(2))}</h{level}>")
        elif re.match(r"^[-*]\s+", stripped):
            if paragraph:
                flush()
            items.append(re.sub(r"^[-*]\s+", "", stripped))
        elif not stripped:
            flush()
        elif items and line.startswith((" ", "\t")):
            items[-1] += " " + stripped                      # a wrapped list item
        else:
            if items:
                flush()
            paragraph.append(stripped)
        i += 1
    flush()
    return _page("\n".join(body), title)


def _display(cell: str) -> str:
    """A CSV cell as shown: a number with more than 6 significant digits rounded to 4 (a review: cells such
    as 0.026443107999511994 made the tables unreadable); integers and text as they are. The CSV keeps them."""
    try:
        value = float(cell)
    except ValueError:
        return cell
    digits = len(re.sub(r"[^0-9]", "", cell.split("e")[0].split("E")[0]).strip("0"))
    if digits <= 6 or not cell.strip() or not re.search(r"[.eE]", cell):
        return cell
    return f"{value:.4g}"


def csv_to_html(text: str, title: str = "") -> str:
    """A standalone HTML page with the CSV ``text`` as one table (the first row its header; numbers shown
    to 4 significant digits, :func:`_display`)."""
    rows = list(csv.reader(io.StringIO(text)))
    rows = rows[:1] + [[_display(c) for c in row] for row in rows[1:]]
    return _page(_table(rows, header=True) if rows else "<p>(empty)</p>", title)


def _page(body: str, title: str) -> str:
    """A standalone HTML page around ``body``."""
    head = f"<title>{html.escape(title)}</title>" if title else ""
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">{head}<style>{_STYLE}</style></head>\n"
            f"<body>\n{body}\n</body></html>\n")


def write_html(source: str | os.PathLike, target: str | os.PathLike) -> Path:
    """Write the HTML twin ``target`` of a generated ``.md`` or ``.csv`` file ``source``, atomically."""
    source, target = Path(source), Path(target)
    text = source.read_text(encoding="utf-8")
    page = (csv_to_html if source.suffix.lower() == ".csv" else markdown_to_html)(text, title=source.name)
    with atomic_target(target) as tmp:      # the project's atomic writer (no temporary file left on failure)
        tmp.write_text(page, encoding="utf-8")
    return target


def write_twins(output) -> None:
    """For every output ``<name>_html`` of a Snakemake rule, :func:`write_html` of its output ``<name>``."""
    names = output.keys() if hasattr(output, "keys") else vars(output).keys()     # a Namedlist, or a namespace
    for name in list(names):
        if name.endswith("_html"):
            write_html(getattr(output, name[: -len("_html")]), getattr(output, name))


def main(argv: list[str] | None = None) -> int:
    """``python -m ddstudies.report.html SOURCE TARGET``: :func:`write_html` (for shell rules)."""
    import sys
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        sys.stderr.write("usage: python -m ddstudies.report.html SOURCE.md|SOURCE.csv TARGET.html\n")
        return 2
    write_html(args[0], args[1])
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
