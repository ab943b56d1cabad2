"""The job progress bar of the commands that run jobs (``run``, ``learning-curve``).

One place for its look (description, bar, done/total, elapsed, remaining, on stderr, kept
on screen when finished) and for how a runner's ``progress(done, total, job)`` callback
moves it, so both commands show the same bar.
"""

from __future__ import annotations

from typing import Any, Callable

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn


class JobProgress:
    """A context manager around a rich progress bar of one task; ``tick`` is the runner's progress callback.

    ``start`` is the description until the first job finishes; then ``label(job)`` of the
    last finished job. ``quiet`` hides the bar.
    """

    def __init__(self, start: str, label: Callable[[Any], str], quiet: bool) -> None:
        self._progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                  TimeElapsedColumn(), TimeRemainingColumn(), console=Console(stderr=True),
                                  disable=quiet, transient=False)
        self._start, self._label = start, label

    def __enter__(self) -> "JobProgress":
        self._progress.__enter__()
        self._task = self._progress.add_task(self._start, total=None)
        return self

    def __exit__(self, *exc: Any) -> None:
        self._progress.__exit__(*exc)

    def tick(self, done: int, total: int, job: Any) -> None:
        self._progress.update(self._task, completed=done, total=total, description=self._label(job))

    def describe(self, text: str) -> None:
        """Show ``text`` as the description (e.g. when the jobs are done)."""
        self._progress.update(self._task, description=text)
