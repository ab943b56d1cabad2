"""What a progress display needs to tell the truth about a run: jobs left per method, their measured costs, an ETA.

The runner tells a progress object the jobs it will run (``plan_jobs``) and each finished job with
its metadata (``job_done``); :class:`JobClock` keeps the count per method, each method's mean
compute seconds per job (the job's own ``timings``), and from them the time left: the compute
the remaining jobs will take at their own method's cost (a method not yet measured at the mean
of those that are), scaled by the wall time the run has taken per second of compute so far
(which accounts for workers running side by side and for the runner's own overhead). No
estimate until a job has finished. It never names a method: jobs carry their method's name.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Sequence


@dataclass
class MethodDone:
    """A method whose last planned job just finished: how many jobs and the compute they took."""

    method: str
    jobs: int
    seconds: float


@dataclass
class JobClock:
    """Jobs left and measured costs per method, the jobs not finished in plan order, and the time left."""

    left: Counter = field(default_factory=Counter)
    planned: Counter = field(default_factory=Counter)
    costs: dict[str, list[float]] = field(default_factory=dict)
    pending: list[Any] = field(default_factory=list)
    compute: float = 0.0

    def plan(self, jobs: Sequence[Any]) -> None:
        """The jobs still to run (each with ``.method`` and ``.key``), in the order they are submitted."""
        self.left = Counter(j.method for j in jobs)
        self.planned = Counter(self.left)
        self.pending = list(jobs)

    def done(self, job: Any, meta: dict[str, Any]) -> MethodDone | None:
        """Count ``job`` finished with its metadata's timings; the method's summary when it was its last job."""
        timings = meta.get("timings") or {}
        seconds = float(sum(v for v in timings.values() if isinstance(v, (int, float))))
        self.costs.setdefault(job.method, []).append(seconds)
        self.compute += seconds
        self.pending = [j for j in self.pending if j.key != job.key]
        if self.left[job.method] > 0:
            self.left[job.method] -= 1
            if self.left[job.method] == 0:
                spent = self.costs[job.method]
                return MethodDone(job.method, len(spent), float(sum(spent)))
        return None

    def running(self) -> Any | None:
        """The first job of the plan not finished yet: running now (workers take jobs in plan order)."""
        return self.pending[0] if self.pending else None

    def seconds_left(self, elapsed: float) -> float | None:
        """Wall seconds left at the measured costs (module docstring); None before a job with a cost finished."""
        measured = {m: sum(c) / len(c) for m, c in self.costs.items() if c}
        if not measured or self.compute <= 0:
            return None
        fallback = sum(measured.values()) / len(measured)
        remaining = sum(n * measured.get(m, fallback) for m, n in self.left.items())
        return remaining * (elapsed / self.compute)
