"""index.html: the report's Markdown rendered in a small styled page, and a check that every
local file the page refers to exists. (Not `html.py`: that would shadow the standard library's
`html` for anything run from this folder.)"""

from __future__ import annotations

import html
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlparse

import markdown

from reports.plots import VERDICT_COLOURS
from reports.sections.summary import OFF

# The summary's "off" (ok, but a closed form missed): amber, apart from every verdict's colour.
OFF_COLOUR = "#ffd54f"

CSS = """
body { font-family: system-ui, sans-serif; max-width: 76rem; margin: 2rem auto; padding: 0 1rem;
       line-height: 1.45; color: #222; }
table { border-collapse: collapse; margin: 0.8rem 0; font-size: 0.9rem; display: block;
        overflow-x: auto; }
th, td { border: 1px solid #bbb; padding: 0.2rem 0.5rem; }
th { background: #f0f0f0; }
td { font-variant-numeric: tabular-nums; }
th, td { text-align: left; }
.num { text-align: right; }
img { max-width: 100%; }
code { background: #f4f4f4; padding: 0 0.2rem; }
p, li { overflow-wrap: anywhere; }
details { margin: 0.6rem 0 1.6rem; }
summary { cursor: pointer; font-weight: 600; }
.verdict { padding: 0 0.3rem; border-radius: 0.2rem; white-space: nowrap; }
"""


def _verdict_css() -> str:
    """The summary's verdict words in the stability maps' colours (`reports.plots`)."""
    rules = []
    for verdict, colour in VERDICT_COLOURS.items():
        text = "white" if verdict in ("diverged", "dissipated", "failed") else "#222"
        name = verdict.replace(" ", "-")
        rules.append(f".verdict-{name} {{ background: {colour}; color: {text}; }}")
    rules.append(f".verdict-{OFF} {{ background: {OFF_COLOUR}; color: #222; }}")
    # the physics gates' pass and fail, as ok and diverged
    rules.append(f".gate-pass {{ background: {VERDICT_COLOURS['ok']}; color: #222; }}")
    rules.append(f".gate-fail {{ background: {VERDICT_COLOURS['diverged']}; color: white; }}")
    return "\n".join(rules) + "\n"


PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>{css}</style>
</head>
<body>
{body}
</body>
</html>
"""


def render_html(markdown_text: str, title: str = "rigidbench report") -> str:
    """index.html: the Markdown converted (tables, fenced code, heading ids as GitHub gives
    them, Markdown inside `<details>`) in a small styled page."""
    extensions = ["tables", "fenced_code", "toc", "md_in_html"]
    body = markdown.markdown(markdown_text, extensions=extensions)
    # a class instead of the same style on each of ~13,000 cells: half the page's bytes
    for cell in ("td", "th"):
        body = body.replace(f'<{cell} style="text-align: left;">', f"<{cell}>")
        body = body.replace(f'<{cell} style="text-align: right;">', f'<{cell} class="num">')
    return PAGE.format(title=html.escape(title), css=CSS + _verdict_css(), body=body)


class _References(HTMLParser):
    """Collects every src and href of a page."""

    def __init__(self):
        super().__init__()
        self.found: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.found += [v for k, v in attrs if k in ("src", "href") and v]


def missing_references(html_path: Path) -> list[str]:
    """Local files (src, href) the HTML page refers to that do not exist beside it."""
    html_path = Path(html_path)
    parser = _References()
    parser.feed(html_path.read_text(encoding="utf-8"))
    local = [
        ref
        for ref in parser.found
        if not urlparse(ref).scheme and not urlparse(ref).netloc and not ref.startswith("#")
    ]
    return [ref for ref in local if not (html_path.parent / unquote(urlparse(ref).path)).exists()]
