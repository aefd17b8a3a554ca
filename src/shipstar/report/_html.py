"""A self-contained HTML report: text, tables and PNG figures embedded as base64 data URIs.

The page loads nothing from outside (no scripts, fonts or images from the network).  A
small inline script records, after the page has loaded, whether every image decoded and
whether anything reached ``window.onerror`` or ``console.error``; it writes that verdict
as JSON into ``<pre id="shipstar-verdict">`` (hidden), where a headless browser's DOM
dump can read it (tests/test_report_browser.py).
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path

from shipstar.errors import ShipstarError

__all__ = ["Report", "VERDICT_ID"]

VERDICT_ID = "shipstar-verdict"

_CSS = """
body { font-family: -apple-system, "Segoe UI", Roboto, "DejaVu Sans", Arial, sans-serif; margin: 0;
       color: #1b1f24; background: #f6f7f9; line-height: 1.45; }
main { max-width: 1120px; margin: 0 auto; padding: 24px 28px 48px; background: #fff;
       box-shadow: 0 0 12px rgba(0,0,0,.06); }
h1 { font-size: 1.7em; margin: 0.2em 0 0.1em; }
h2 { font-size: 1.3em; margin-top: 1.8em; border-bottom: 2px solid #e3e6ea; padding-bottom: 4px; }
h3 { font-size: 1.05em; margin-top: 1.2em; }
p.sub { color: #59636e; margin-top: 0; }
table { border-collapse: collapse; margin: 0.6em 0 1em; font-size: 0.92em; }
th, td { border: 1px solid #d5d9de; padding: 3px 9px; text-align: right; }
th { background: #eef1f4; }
td.l, th.l { text-align: left; }
tr.seed td { color: #6a4c93; background: #faf7fd; }
figure { margin: 1em 0 1.6em; }
figure img { max-width: 100%; height: auto; border: 1px solid #e3e6ea; }
figcaption { color: #444c56; font-size: 0.92em; margin-top: 4px; }
pre { background: #f3f4f6; padding: 8px 10px; overflow-x: auto; font-size: 0.88em; }
code { background: #f3f4f6; padding: 0 3px; }
.note { border-left: 4px solid #d4a72c; background: #fff8e5; padding: 6px 12px; }
nav ul { columns: 2; }
"""

_SCRIPT = """
(function () {
  var problems = [];
  window.addEventListener("error", function (e) {
    var t = e.target;
    problems.push("error: " + (e.message || (t && (t.alt || t.src || t.tagName)) || "unknown"));
  }, true);
  var original = console.error;
  console.error = function () {
    problems.push("console.error: " + Array.prototype.join.call(arguments, " "));
    return original.apply(console, arguments);
  };
  window.addEventListener("load", function () {
    var images = Array.prototype.slice.call(document.images);
    var bad = images.filter(function (i) { return !(i.complete && i.naturalWidth > 0); })
                    .map(function (i) { return i.alt || i.src.slice(0, 40); });
    var verdict = {n_images: images.length, n_loaded: images.length - bad.length,
                   not_loaded: bad, errors: problems};
    document.getElementById("%s").textContent = JSON.stringify(verdict);
  });
})();
""" % VERDICT_ID


def _esc(text) -> str:
    return html.escape(str(text), quote=True)


def _anchor(text: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in text.lower()).strip("-")


@dataclass
class Report:
    """An HTML report built block by block.

    Examples
    --------
    >>> r = Report("Session 7", subtitle="two sensors")
    >>> r.section("Results")
    >>> r.table(["method", "rms_arcsec"], [["joint", "0.51"]])
    >>> html_text = r.to_html()
    """

    title: str
    subtitle: str = ""
    _blocks: list = field(default_factory=list)
    _sections: list = field(default_factory=list)
    n_figures: int = 0

    def section(self, title: str) -> None:
        """Start a section (listed in the contents)."""
        anchor = f"s{len(self._sections) + 1}-{_anchor(title)}"
        self._sections.append((anchor, title))
        self._blocks.append(f'<h2 id="{anchor}">{_esc(title)}</h2>')

    def heading(self, text: str) -> None:
        self._blocks.append(f"<h3>{_esc(text)}</h3>")

    def paragraph(self, text: str, *, note: bool = False) -> None:
        """A paragraph of plain text (escaped); ``note`` draws it as a highlighted remark."""
        cls = ' class="note"' if note else ""
        self._blocks.append(f"<p{cls}>{_esc(text)}</p>")

    def preformatted(self, text: str) -> None:
        self._blocks.append(f"<pre>{_esc(text)}</pre>")

    def bullets(self, items) -> None:
        self._blocks.append("<ul>" + "".join(f"<li>{_esc(i)}</li>" for i in items) + "</ul>")

    def table(self, header, rows, *, left_columns: int = 1, row_classes=None, groups=None) -> None:
        """A table; the first ``left_columns`` columns are left-aligned (labels), the rest
        right-aligned (numbers).  ``row_classes`` (optional, one per row) e.g. ``"seed"``;
        ``groups`` (optional) a header row above, ``[(label, n_columns), ...]``."""
        def cell(tag, k, v):
            cls = ' class="l"' if k < left_columns else ""
            return f"<{tag}{cls}>{_esc(v)}</{tag}>"

        head = "<tr>" + "".join(cell("th", k, h) for k, h in enumerate(header)) + "</tr>"
        if groups:
            if sum(n for _, n in groups) != len(header):
                raise ShipstarError(f"table groups span {sum(n for _, n in groups)} columns, the header {len(header)}")
            head = "<tr>" + "".join(f'<th colspan="{int(n)}">{_esc(g)}</th>' for g, n in groups) + "</tr>" + head
        body = []
        for i, row in enumerate(rows):
            if len(row) != len(header):
                raise ShipstarError(f"table row {i} has {len(row)} cells, the header {len(header)}")
            cls = f' class="{_esc(row_classes[i])}"' if row_classes and row_classes[i] else ""
            body.append(f"<tr{cls}>" + "".join(cell("td", k, v) for k, v in enumerate(row)) + "</tr>")
        self._blocks.append("<table>" + head + "".join(body) + "</table>")

    def figure(self, png: bytes, caption: str, alt: str) -> None:
        """An embedded PNG (bytes) with a caption; ``alt`` names it (and the browser check)."""
        if not isinstance(png, (bytes, bytearray)) or not bytes(png[:8]) == b"\x89PNG\r\n\x1a\n":
            raise ShipstarError(f"figure {alt!r} is not PNG data")
        self.n_figures += 1
        data = base64.b64encode(bytes(png)).decode("ascii")
        self._blocks.append(f'<figure><img src="data:image/png;base64,{data}" alt="{_esc(alt)}">'
                            f"<figcaption>Figure {self.n_figures}. {_esc(caption)}</figcaption></figure>")

    def to_html(self) -> str:
        """The whole page (UTF-8 text)."""
        nav = ""
        if len(self._sections) > 1:
            nav = "<nav><ul>" + "".join(f'<li><a href="#{a}">{_esc(t)}</a></li>' for a, t in self._sections) \
                + "</ul></nav>"
        sub = f'<p class="sub">{_esc(self.subtitle)}</p>' if self.subtitle else ""
        return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
                "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
                f"<title>{_esc(self.title)}</title><style>{_CSS}</style><script>{_SCRIPT}</script></head>\n"
                f"<body><main><h1>{_esc(self.title)}</h1>{sub}{nav}\n" + "\n".join(self._blocks)
                + f'\n<pre id="{VERDICT_ID}" hidden></pre></main></body></html>\n')

    def write(self, path) -> Path:
        """Write the page atomically (temporary file + rename); returns the path."""
        from shipstar._atomic import atomic_write_text

        return atomic_write_text(path, self.to_html(), what="the report")
