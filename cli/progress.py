"""The job progress bar of the commands that run jobs (``run``, ``learning-curve``).

One place for its look (description, bar, done/total, elapsed, remaining, on stderr, kept
on screen when finished) and for how a runner's ``progress(done, total, job)`` callback
moves it, so both commands show the same bar.
"""

from __future__ import annotations

from typing import Any, Callable

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn, TimeElapsedColumn
from rich.text import Text


class RunRemainingColumn(ProgressColumn):
    """Time left at the run's own pace: elapsed / jobs finished here x jobs left (rich's default estimates the
    speed over the last 30 s, which between jobs of minutes reads seconds); -:--:-- until a job finishes."""

    def render(self, task: Any) -> Text:
        done = (task.completed or 0) - task.fields.get("first", 0)
        if not task.total or done <= 0 or task.elapsed is None:
            return Text("-:--:--", style="progress.remaining")
        left = max(0.0, task.elapsed / done * (task.total - task.completed))
        h, rest = divmod(int(round(left)), 3600)
        return Text(f"{h}:{rest // 60:02d}:{rest % 60:02d} left", style="progress.remaining")


class JobProgress:
    """A context manager around a rich progress bar of one task; ``tick`` is the runner's progress callback.

    ``start`` is the description while the data are prepared; ``running`` once the runner has
    planned the jobs (the total is then known); after each finished job ``label(job)`` names the
    last one finished (not the ones running). ``quiet`` hides the bar.
    """

    def __init__(self, start: str, label: Callable[[Any], str], quiet: bool, running: str | None = None) -> None:
        self._progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                  TimeElapsedColumn(), RunRemainingColumn(), console=Console(stderr=True),
                                  disable=quiet, transient=False)
        self._start, self._label, self._running = start, label, running or start

    def __enter__(self) -> "JobProgress":
        self._progress.__enter__()
        self._task = self._progress.add_task(self._start, total=None)
        return self

    def __exit__(self, *exc: Any) -> None:
        self._progress.__exit__(*exc)

    def planned(self, done: int, total: int) -> None:
        """The runner has planned ``total`` jobs, ``done`` of them already stored (a resume): the total is shown
        from now on, and the remaining time counts only the jobs finished from here."""
        self._progress.reset(self._task, total=total, completed=done, first=done, description=self._running)

    def tick(self, done: int, total: int, job: Any) -> None:
        """The runner's progress callback: ``job`` has finished, ``done`` of ``total``."""
        self._progress.update(self._task, completed=done, total=total, description=self._label(job))

    __call__ = tick

    def describe(self, text: str) -> None:
        """Show ``text`` as the description (e.g. when the jobs are done)."""
        self._progress.update(self._task, description=text)
