"""The shape every section shares: a heading, its opening paragraph (most often how to read
it), then blocks between blank lines; and a case's figure, or why it is missing."""

from __future__ import annotations

from pathlib import Path

from markdown.extensions.toc import slugify

from reports.convergence import MIN_FIT_POINTS
from reports.figures import figure_link


def _titled(heading: str, title: str, lead: str, blocks: tuple[str, ...]) -> list[str]:
    lines = [f"{heading} {title}", "", lead]
    for block in blocks:
        lines += ["", block]
    return lines


def section(title: str, lead: str, *blocks: str) -> list[str]:
    """A `## title` section: `lead` (its opening paragraph), then each block."""
    return _titled("##", title, lead, blocks)


def subsection(title: str, lead: str, *blocks: str) -> list[str]:
    """A `### title` subsection as `section`, led by a blank line to follow the lines before."""
    return ["", *_titled("###", title, lead, blocks)]


def case_figure(figures: dict, case: str, kind: str, out: Path, alt: str) -> str:
    """The case's figure of `kind` as a Markdown image, or a line saying why there is none."""
    link = figure_link(figures, (case, kind), out, f"{alt}, {case}")
    if link is None:
        return (
            f"*No {alt} figure: nothing to show (a convergence plot needs {MIN_FIT_POINTS} or "
            "more dt swept; the other figures need a valid run).*"
        )
    return link


def anchor(title: str) -> str:
    """The id of a heading titled `title` (Markdown, backticks allowed): what Python-Markdown's
    toc extension (index.html) and GitHub (report.md) both give it."""
    return slugify(title.replace("`", ""), "-")


def case_title(case: str) -> str:
    """The heading of a case's section."""
    return f"Case `{case}`"


def case_link(case: str) -> str:
    """A Markdown link to a case's section."""
    return f"[{case}](#{anchor(case_title(case))})"


def folded(summary: str, lines: list[str]) -> list[str]:
    """`lines` in a `<details>` block opened by clicking `summary`: Markdown inside is rendered
    by GitHub and by Python-Markdown's md_in_html (the markdown="1" attribute)."""
    return ["", f'<details markdown="1"><summary>{summary}</summary>', "", *lines, "", "</details>"]


def contents(parts: list[list[str]]) -> list[str]:
    """The table of contents of the report's `parts` (each opening with its "## " heading):
    one link per section, the cases on one line."""
    items, cases = [], []
    for part in parts:
        title = part[0].removeprefix("## ")
        if title.startswith("Case `"):
            name = title.removeprefix("Case `").removesuffix("`")
            cases.append(f"[{name}](#{anchor(title)})")
            if len(cases) == 1:
                items.append(None)  # where the cases' line goes
        else:
            items.append(f"[{title}](#{anchor(title)})")
    line = "Cases: " + " · ".join(cases)
    return ["## Contents", "", *(f"- {line if item is None else item}" for item in items)]
