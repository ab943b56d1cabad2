"""The run's progress bar: the total shown once the jobs are planned, the time left at the run's own pace
(jobs finished here, not the jobs a resume found done), and the label naming the last finished job."""

from __future__ import annotations

from types import SimpleNamespace

from enginebench.cli.progress import JobProgress, RunRemainingColumn


def _left(completed, total, first, elapsed) -> str:
    task = SimpleNamespace(completed=completed, total=total, fields={"first": first}, elapsed=elapsed)
    return str(RunRemainingColumn().render(task))


def test_time_left_is_the_runs_average_job_time_times_the_jobs_left():
    assert _left(1, 10, 0, 20.0) == "0:03:00 left"            # 20 s a job, 9 left
    assert _left(6, 10, 4, 100.0) == "0:03:20 left"           # a resume: 2 jobs done here in 100 s, 4 left
    assert _left(4, 10, 4, 100.0) == "-:--:--"                # nothing finished yet in this session
    assert _left(10, 10, 0, 50.0) == "0:00:00 left"


def test_the_total_is_known_once_planned_and_the_label_names_the_last_finished_job():
    bar = JobProgress("x: preparing", lambda job: f"x: last done {job}", quiet=True, running="x: running")
    with bar:
        task = bar._progress.tasks[0]
        assert task.total is None and task.description == "x: preparing"
        bar.planned(3, 12)
        assert (task.total, task.completed, task.fields["first"], task.description) == (12, 3, 3, "x: running")
        bar(4, 12, "arx r0")
        assert task.completed == 4 and task.description == "x: last done arx r0"



def test_the_measured_eta_counts_down_between_jobs():
    task = SimpleNamespace(completed=2, total=10, fields={"first": 0, "eta": 100.0, "eta_at": 30.0}, elapsed=50.0)
    assert str(RunRemainingColumn().render(task)) == "0:01:20 left"  # 100 s estimated 20 s ago


def test_the_label_names_the_running_job_and_a_methods_last_job_prints_its_line(capsys):
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class J:
        key: str
        method: str
        repetition: int

    jobs = [J("a0", "arx", 0), J("a1", "arx", 1), J("n0", "narx", 0)]
    bar = JobProgress("x: preparing", lambda job: f"x: last done {job.key}", quiet=False, running="x: running",
                      running_label=lambda job: f"x: running {job.method} r{job.repetition}")
    with bar:
        task = bar._progress.tasks[0]
        bar.planned(0, 3)
        bar.plan_jobs(jobs)
        assert task.description == "x: running arx r0"
        bar.job_done(jobs[0], {"timings": {"fit": 2.0}})
        bar(1, 3, jobs[0])
        assert task.description == "x: running arx r1" and task.fields["eta"] is not None
        bar.job_done(jobs[1], {"timings": {"fit": 4.0}})
        bar(2, 3, jobs[1])
        assert task.description == "x: running narx r0"
    assert "arx: 2 jobs done, 3.0 s each (6 s of compute)" in capsys.readouterr().err
