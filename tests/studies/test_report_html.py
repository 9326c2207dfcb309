"""HTML copies of the generated tables for the Snakemake report (which offers .md and .csv for download
only: a review found every table of the HTML report a bare link)."""
from html.parser import HTMLParser

from ddstudies.report.html import csv_to_html, markdown_to_html, write_html

MD = """# Table 4.1: FETI-FETI (study `t`)

cond: Lanczos estimate; **dev.**: (ours - thesis)/|thesis| < 1 & > 0.

| 1/H_b | (I) cond | (I) cond thesis |
|---|---|---|
| 2 | 2.5536 | 2.5536 |
| 4 | 2.7185† | -- |

- first point
  wrapped
- second

† beyond the thesis's table
"""


class Cells(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.cells, self._in = [], [], False

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self._in = tag in ("td", "th")

    def handle_data(self, data):
        if self._in:
            self.cells.append(data)
            self._in = False


def test_markdown_tables_headings_and_lists():
    page = markdown_to_html(MD, title="t.md")
    parsed = Cells()
    parsed.feed(page)
    assert parsed.tags.count("table") == 1 and parsed.tags.count("tr") == 3 and parsed.tags.count("th") == 3
    assert parsed.cells == ["1/H_b", "(I) cond", "(I) cond thesis", "2", "2.5536", "2.5536", "4", "2.7185†", "--"]
    assert "<h1>Table 4.1: FETI-FETI (study <code>t</code>)</h1>" in page
    assert "<b>dev.</b>: (ours - thesis)/|thesis| &lt; 1 &amp; &gt; 0." in page
    assert "<li>first point wrapped</li><li>second</li>" in page
    assert "<p>† beyond the thesis&#x27;s table</p>" in page or "<p>† beyond the thesis's table</p>" in page


def test_csv_and_write_html(tmp_path):
    page = csv_to_html("a,b\n1,x<y\n")
    assert "<th>a</th><th>b</th>" in page and "<td>x&lt;y</td>" in page
    source = tmp_path / "t.md"
    source.write_text(MD)
    target = write_html(source, tmp_path / "t.html")
    assert target.read_text().startswith("<!DOCTYPE html>") and sorted(p.name for p in tmp_path.iterdir()) == [
        "t.html", "t.md"]


def test_csv_numbers_are_shown_rounded():
    """Long floats of a summary CSV are shown to 4 significant digits (a review: 223 cells such as
    0.026443107999511994 made the table overflow); short numbers, integers and text stay as written."""
    page = csv_to_html("method,seconds,rtol,n\nactive-set,0.026443107999511994,1e-06,12\n")
    assert "<td>0.02644</td>" in page and "<td>1e-06</td>" in page and "<td>12</td>" in page
    assert "<td>active-set</td>" in page and "white-space:nowrap" in page
