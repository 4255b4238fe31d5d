"""The report in a real browser: headless Chromium (the system's package, never a downloaded
build) driven by Playwright, and what a reader's browser sees of index.html.

`inspect_page` is what the browser test checks (images and animations loaded, every
table-of-contents link landing on an element, console errors, page width); `screenshot` makes
the README's picture of the summary (`python -m reports.browser REPORT_DIR OUT.png`).
"""

from __future__ import annotations

import shutil
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from cases.errors import InputError

# The viewport a reader's laptop gives: 1280 px wide (the width), 800 px high.
VIEWPORT = {"width": 1280, "height": 800}
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")


def chromium_path() -> str | None:
    """The system's Chromium executable, or None (Debian: `apt-get install chromium`)."""
    return next((path for name in CHROMIUM_NAMES if (path := shutil.which(name))), None)


@contextmanager
def page_of(html: Path, viewport: dict = VIEWPORT):
    """(a Playwright page with `html` loaded, the list its console errors are collected in)."""
    from playwright.sync_api import sync_playwright

    executable = chromium_path()
    if executable is None:
        raise InputError("no Chromium found: install it (Debian: apt-get install chromium)")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport=viewport)
            errors: list[str] = []
            page.on("console", lambda m: m.type == "error" and errors.append(m.text))
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(Path(html).resolve().as_uri(), wait_until="load")
            yield page, errors
        finally:
            browser.close()


@dataclass
class PageReport:
    """What the browser saw: images that did not load (src), contents links whose target is
    missing (href), console errors, the page's scroll width and the viewport's width (px)."""

    broken_images: list[str]
    dead_links: list[str]
    console_errors: list[str]
    scroll_width: int
    viewport_width: int


def inspect_page(html: Path) -> PageReport:
    """Load `html` at VIEWPORT, open every `<details>` (folded figures load too), and check it."""
    with page_of(html) as (page, errors):
        page.evaluate("document.querySelectorAll('details').forEach(d => d.open = true)")
        page.wait_for_load_state("networkidle")
        broken = page.evaluate(
            "Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0))"
            ".map(i => i.getAttribute('src'))"
        )
        dead = page.evaluate(
            "Array.from(document.querySelectorAll('a[href^=\"#\"]'))"
            ".map(a => a.getAttribute('href'))"
            ".filter(h => !document.getElementById(decodeURIComponent(h.slice(1))))"
        )
        width = page.evaluate("document.documentElement.scrollWidth")
        return PageReport(broken, dead, list(errors), width, VIEWPORT["width"])


def screenshot(html: Path, out: Path, selector: str = "#summary") -> Path:
    """A PNG of the first screen from the heading `selector` on: what a reader sees first."""
    with page_of(html) as (page, _):
        page.locator(selector).scroll_into_view_if_needed()
        page.evaluate(f"window.scrollTo(0, document.querySelector('{selector}').offsetTop - 16)")
        page.screenshot(path=str(out))
    return Path(out)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python -m reports.browser REPORT_DIR OUT.png")
    print(screenshot(Path(sys.argv[1]) / "index.html", Path(sys.argv[2])))
