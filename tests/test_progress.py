"""The progress bar in a log: a line each tenth of the way, where rich alone shows only the end."""

import io

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn

from comparators.progress import Bar, stage

COLUMNS = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())


def _logged(total: int, disable: bool = False) -> list[str]:
    out = io.StringIO()  # no terminal, as a file or a CI log
    with Bar(*COLUMNS, console=Console(file=out, width=100), disable=disable) as bar:
        task = bar.add_task("work", total=total)
        for _ in range(total):
            bar.update(task, advance=1)
    return out.getvalue().splitlines()


def test_a_log_shows_the_bar_each_tenth_of_the_way_and_at_the_end():
    lines = _logged(25)
    # tenths crossed at 2.5, 5, 7.5, ... runs; the last line is rich's own, at the end
    assert [line.split()[-2] for line in lines] == [
        f"{n}/25" for n in (3, 5, 8, 10, 13, 15, 18, 20, 23, 25)
    ]
    assert all(line.startswith("━") and line.endswith("work") for line in lines)


def test_a_short_task_prints_no_more_lines_than_it_has_steps():
    assert [line.split()[-2] for line in _logged(3)] == ["1/3", "2/3", "3/3"]


def test_the_counts_line_up_however_long_the_description():
    """The description, of any width, ends each log line: the counts stand in one column."""
    out = io.StringIO()
    with Bar(*COLUMNS, console=Console(file=out, width=100)) as bar:
        task = bar.add_task("a", total=20)
        for k in range(20):
            bar.update(task, advance=1, description="x" * (1 + 7 * k % 30))
    lines = out.getvalue().splitlines()
    ends = {line.index("/20") for line in lines}
    assert len(lines) == 10 and len(ends) == 1


def test_a_disabled_bar_prints_nothing():
    assert _logged(25, disable=True) == []


def test_a_stage_in_a_log_prints_its_text_and_each_update():
    """A spinner shows nothing in a log: the stage prints what it is doing instead, as the
    run and animate commands step from run to run."""
    out = io.StringIO()
    with stage(Console(file=out, width=100), "running slide") as status:
        status.update("running slide on mujoco Euler")
        status.update("running slide on reference euler")
    assert out.getvalue().splitlines() == [
        "running slide",
        "running slide on mujoco Euler",
        "running slide on reference euler",
    ]
