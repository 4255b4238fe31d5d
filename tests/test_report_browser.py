"""The quick report's index.html in headless Chromium: every image and animation loads, every
contents link lands on an element, no console error, no page wider than a 1280 px viewport,
and the verdicts are on the first screen.

Needs the system's Chromium (`apt-get install chromium`) and Playwright (in the `test` extra).
Without Chromium the test is skipped, unless RIGIDBENCH_REQUIRE_BROWSER is set (`.ci/run`
sets it, so CI fails instead).
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from reports.browser import VIEWPORT, chromium_path, inspect_page, page_of

# The core cases and a bounce (the summary's closed forms and a contact validation table),
# every installed engine: the quick report's page elements at a fraction of its time.
CASES = ("seed_cube", "free_spin_cube", "tumbling_box", "dropped_cube", "bounce")
# Layout positions are fractional: a heading scrolled to the top sits within a pixel of 0.
SUBPIXEL = 1.0

if chromium_path() is None and not os.environ.get("RIGIDBENCH_REQUIRE_BROWSER"):
    pytest.skip("no Chromium: apt-get install chromium", allow_module_level=True)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("browser") / "report"
    args = ["report", "--quick", "--cases", *CASES, "--out", str(out)]
    proc = subprocess.run(
        [sys.executable, "-m", "reports.cli", *args], capture_output=True, text=True, timeout=900
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out / "index.html"


def test_the_page_loads_whole_and_fits_the_viewport(report):
    seen = inspect_page(report)
    assert seen.broken_images == [], "images that did not load"
    assert seen.dead_links == [], "contents links without a target"
    assert seen.console_errors == []
    assert seen.scroll_width <= seen.viewport_width, "the page scrolls sideways"


def test_the_verdicts_are_on_the_first_screen(report):
    with page_of(report) as (page, _):
        table = page.locator("#summary ~ table").first
        box = table.bounding_box()
        assert box is not None and box["y"] < VIEWPORT["height"], "summary table below the fold"
        assert table.locator(".verdict").count() >= len(CASES)


def test_every_case_is_one_click_away(report):
    with page_of(report) as (page, _):
        for case in CASES:
            page.locator("#contents ~ ul a", has_text=case).first.click()
            heading = page.locator(f"#case-{case.replace('.', '')}")
            box = heading.bounding_box()
            assert box is not None and -SUBPIXEL <= box["y"] < VIEWPORT["height"], case
