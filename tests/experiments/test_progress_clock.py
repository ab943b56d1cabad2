"""The progress display's arithmetic: jobs left per method, their measured costs and the time left."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from enginebench.experiments.progress import JobClock, MethodDone


@dataclass(frozen=True)
class J:
    key: str
    method: str


def test_time_left_is_the_remaining_jobs_at_their_own_methods_cost_scaled_by_wall_per_compute():
    jobs = [J("a0", "fast"), J("a1", "fast"), J("b0", "slow"), J("b1", "slow"), J("c0", "new")]
    clock = JobClock()
    clock.plan(jobs)
    assert clock.seconds_left(5.0) is None and clock.running() == jobs[0]  # nothing measured yet
    assert clock.done(jobs[0], {"timings": {"fit": 1.0, "predict": 1.0}}) is None
    assert clock.done(jobs[2], {"timings": {"fit": 10.0}}) is None
    # left: fast 1 x 2 s, slow 1 x 10 s, new 1 x the mean of the measured methods (6 s) = 18 s of compute;
    # the run took 6 s of wall for 12 s of compute (two workers): 9 s of wall left
    assert clock.seconds_left(6.0) == pytest.approx(9.0)
    assert clock.running() == jobs[1]
    assert clock.done(jobs[1], {"timings": {"fit": 4.0}}) == MethodDone("fast", 2, 6.0)


def test_a_job_without_timings_costs_nothing_and_a_failed_one_counts():
    clock = JobClock()
    jobs = [J("a", "m"), J("b", "m")]
    clock.plan(jobs)
    assert clock.done(jobs[0], {"status": "failed"}) is None
    assert clock.seconds_left(3.0) is None  # no compute measured: no estimate rather than a wrong one
    assert clock.done(jobs[1], {"timings": {"fit": 2.0}}) == MethodDone("m", 2, 2.0)
    assert clock.running() is None and clock.seconds_left(3.0) == 0.0
