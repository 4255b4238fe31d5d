"""The shape every section shares: a heading, its opening paragraph (most often how to read
it), then blocks between blank lines; and a case's figure, or why it is missing."""

from __future__ import annotations

from pathlib import Path

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
