"""How long commands show their progress: the bar of counted work (the sweep, the bench, an
animation's drawing) and the spinner of a stage that has no count."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import Progress, SpinnerColumn, TaskID, TextColumn, TimeElapsedColumn

# Lines a task prints where no terminal shows the bar: one each tenth of the way.
LOGGED_STEPS = 10


class Bar(Progress):
    """rich's progress bar. Where its console is no terminal (a file, a CI log), rich draws the
    bar only when it stops; this one also prints the bar's line each tenth of the way, so that
    a log shows long work moving, with the task's description last: descriptions differ in
    width, and the bars and counts before them then line up from line to line."""

    def __init__(self, *columns, **kwargs):
        super().__init__(*columns, **kwargs)
        self._logged: dict = {}  # task id: the last tenth printed

    def make_tasks_table(self, tasks):
        # rich lays out the table once while it builds its console (`live`), before there is
        # a console to ask
        if not hasattr(self, "live") or self.console.is_terminal:
            return super().make_tasks_table(tasks)
        columns = self.columns
        described = [c for c in columns if "task.description" in getattr(c, "text_format", "")]
        self.columns = tuple(c for c in columns if c not in described) + tuple(described)
        try:
            return super().make_tasks_table(tasks)
        finally:
            self.columns = columns

    def update(self, task_id, **kwargs) -> None:
        super().update(task_id, **kwargs)
        if self.disable or self.console.is_terminal:
            return
        task = next(t for t in self.tasks if t.id == task_id)
        if not task.total or task.finished:  # no total to divide, or rich's last line is due
            return
        step = int(LOGGED_STEPS * task.completed / task.total)
        if step > self._logged.get(task_id, 0):
            self._logged[task_id] = step
            self.console.print(self.make_tasks_table([task]))


class Stage:
    """The spinner of a stage whose text changes as it goes (the run it is on). On a terminal
    the spinner's text changes in place; in a file or a log each new text is printed as a
    line, since rich shows no spinner there."""

    def __init__(self, console: Console, spinner: Progress, task: TaskID):
        self._console = console
        self._spinner = spinner
        self._task = task

    def update(self, text: str, logged: bool = True) -> None:
        """`logged=False`: the spinner alone, for updates too many for a log's lines."""
        self._spinner.update(self._task, description=text)
        if logged and not self._console.is_terminal:
            self._console.print(text, markup=False, soft_wrap=True)


@contextmanager
def stage(console: Console, text: str) -> Iterator[Stage]:
    """A spinner saying `text` and the time since the stage began on a terminal, for a long
    stage without steps to count (the compile, a run, the scaling measurement); in a file or
    a log, `text` once as the stage starts, and each update as a line."""
    if not console.is_terminal:
        console.print(text, markup=False, soft_wrap=True)
    columns = (SpinnerColumn(), TextColumn("{task.description}", markup=False), TimeElapsedColumn())
    # off where no terminal shows it: rich would print an empty line as it stopped
    off = not console.is_terminal
    with Progress(*columns, console=console, transient=True, disable=off) as spinner:
        yield Stage(console, spinner, spinner.add_task(text, total=None))
