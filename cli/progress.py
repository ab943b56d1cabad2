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

from enginebench.experiments.progress import JobClock


class RunRemainingColumn(ProgressColumn):
    """Time left from the measured cost of each method's jobs (``experiments.progress.JobClock``: the jobs left
    at their own method's cost), counting down between finished jobs; without a job's timings, elapsed / jobs
    finished here x jobs left (rich's default estimates the speed over the last 30 s, which between jobs of
    minutes reads seconds); -:--:-- until a job finishes."""

    def render(self, task: Any) -> Text:
        done = (task.completed or 0) - task.fields.get("first", 0)
        if not task.total or done <= 0 or task.elapsed is None:
            return Text("-:--:--", style="progress.remaining")
        eta = task.fields.get("eta")
        if eta is not None:
            left = max(0.0, eta - (task.elapsed - task.fields.get("eta_at", 0.0)))
        else:
            left = max(0.0, task.elapsed / done * (task.total - task.completed))
        h, rest = divmod(int(round(left)), 3600)
        return Text(f"{h}:{rest // 60:02d}:{rest % 60:02d} left", style="progress.remaining")


class JobProgress:
    """A context manager around a rich progress bar of one task; ``tick`` is the runner's progress callback.

    ``start`` is the description while the data are prepared; ``running`` once the runner has
    planned the jobs (the total is then known); after each finished job ``running_label(job)`` names
    the job running now (the first unfinished one in plan order), or ``label(job)`` the last one
    finished where the runner told no plan. A method's last job prints one line with its jobs and
    their compute time; the time left comes from each method's measured cost. ``quiet`` hides the bar.
    """

    def __init__(self, start: str, label: Callable[[Any], str], quiet: bool, running: str | None = None,
                 running_label: Callable[[Any], str] | None = None) -> None:
        self._progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                  TimeElapsedColumn(), RunRemainingColumn(), console=Console(stderr=True),
                                  disable=quiet, transient=False)
        self._start, self._label, self._running = start, label, running or start
        self._running_label = running_label
        self._quiet = quiet
        self._clock = JobClock()

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

    def plan_jobs(self, jobs: Any) -> None:
        """The jobs the runner will run, in order: counted per method for the time left and the running label."""
        self._clock.plan(jobs)
        first = self._clock.running()
        if first is not None and self._running_label:
            self._progress.update(self._task, description=self._running_label(first))

    def job_done(self, job: Any, meta: dict[str, Any]) -> None:
        """A finished job's metadata: its compute time counts towards its method's cost; the method's line is
        printed above the bar when its last job is done."""
        finished = self._clock.done(job, meta)
        if finished is not None and not self._quiet:
            self._progress.console.print(f"{finished.method}: {finished.jobs} job{'s' * (finished.jobs != 1)} done, "
                                         f"{finished.seconds / finished.jobs:.1f} s each ({finished.seconds:.0f} s "
                                         "of compute)")

    def tick(self, done: int, total: int, job: Any) -> None:
        """The runner's progress callback: ``job`` has finished, ``done`` of ``total``; the description names the
        job running now (the first unfinished in plan order) once the plan is known, else the last finished."""
        task = self._progress.tasks[self._task]
        elapsed = task.elapsed or 0.0
        eta = self._clock.seconds_left(elapsed)
        running = self._clock.running()
        text = self._running_label(running) if running is not None and self._running_label else self._label(job)
        self._progress.update(self._task, completed=done, total=total, description=text, eta=eta, eta_at=elapsed)

    __call__ = tick

    def describe(self, text: str) -> None:
        """Show ``text`` as the description (e.g. when the jobs are done)."""
        self._progress.update(self._task, description=text)
