"""Faults of the machine and the store: each is detected, reported in one line, and loses no finished job.

* the process killed mid-run (SIGKILL): ``tests/experiments/test_runner.py::test_killed_process_resumes_from_the_command_line``
  (finished jobs readable, ``--resume`` completes); here: a write cut short leaves only a
  hidden temporary file that is never read as a job and is removed on resume;
* the disk full while writing a result: the run stops with an error naming the store and
  saying "disk full", no partial job file, earlier jobs readable, ``--resume`` finishes;
* two processes writing runs into one store at once: distinct run ids, no clobbered
  files, ``latest`` is the run created last;
* a damaged job file: ``table`` and ``runs show`` refuse naming the file; ``--resume``
  treats that job as unfinished and recomputes only it.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.errors import StoreError
from enginebench.experiments.runner import run_experiment
from enginebench.results import atomic as store_mod  # the store writes every file through atomic._write_bytes
from enginebench.results.store import RunStore
from helpers import interrupt_after, toy_spec

KEY = ["method", "repetition", "split", "metric"]


def fault_spec(dataset, **changes):
    return toy_spec(dataset, **{"name": "fault-exp", "seed": 5, "train_size": 100, "methods": {
        "naive-mean": {}, "krls": {"gamma_grid": [-1, 0, 2], "lambda_grid": [-2, -1, 2]}}, **changes})


def exp_file(tmp_path: Path, dataset: Path, repetitions: int = 3) -> Path:
    path = tmp_path / "exp.toml"
    path.write_text(textwrap.dedent(f'''
        name = "fault-exp"
        dataset = "{dataset}"
        targets = ["y"]
        repetitions = {repetitions}
        seed = 5
        train_size = 100
        [selection]
        resamples = 2
        [methods.naive-mean]
        [methods.krls]
        gamma_grid = [-1, 0, 2]
        lambda_grid = [-2, -1, 2]
    '''))
    return path


def values(metrics):
    """Metric values without timings, in a fixed order (for comparing runs)."""
    keep = metrics[~metrics["metric"].str.startswith("time_")].sort_values(KEY)
    return keep["value"].to_numpy()


def leftovers(run) -> list[str]:
    """Hidden (temporary) files anywhere in a run folder."""
    return sorted(p.name for p in run.path.rglob(".*"))


# ----------------------------------------------------------------------------- killed mid-write
def test_a_write_cut_short_is_never_read_as_a_job_and_is_removed_on_resume(toy_parquet, tmp_path):
    spec = fault_spec(toy_parquet)
    store = RunStore(tmp_path / "runs")

    run = interrupt_after(spec, store, workers=1)
    # what a SIGKILL during the write of the third job leaves behind: a partial temporary file
    partial = run.jobs_dir / ".y__w0__published__krls__r001.parquet.abc123.tmp"
    partial.write_bytes(b"PAR1\x00\x01 half a job")
    assert len(run.finished_jobs()) == 2 and len(run.metrics()) > 0
    run_experiment(spec, store, workers=1, resume=run)
    assert not partial.exists() and leftovers(run) == []
    assert len(run.finished_jobs()) == 6


# ----------------------------------------------------------------------------- disk full
def full_disk_after(n_ok: int, monkeypatch) -> dict:
    """Let ``n_ok`` job files be written, then fail every write with ENOSPC after writing half of it."""
    state = {"jobs": 0, "full": False}
    real = store_mod._write_bytes

    def write(fh, data, path):
        if not state["full"] and ".parquet." in path.name and path.parent.name == "jobs":  # not a selection table
            state["jobs"] += 1
            state["full"] = state["jobs"] > n_ok
        if state["full"]:
            real(fh, data[: len(data) // 2], path)  # the disk fills up part-way through the file
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fh, data, path)

    monkeypatch.setattr(store_mod, "_write_bytes", write)
    return state


def test_disk_full_stops_the_run_keeps_earlier_jobs_and_resumes(toy_parquet, tmp_path, monkeypatch):
    spec = fault_spec(toy_parquet)
    reference = run_experiment(spec, RunStore(tmp_path / "ref"), workers=1).run.metrics()
    store = RunStore(tmp_path / "runs")
    full_disk_after(2, monkeypatch)
    with pytest.raises(StoreError) as err:
        run_experiment(spec, store, workers=1)
    message = str(err.value)
    assert "disk full" in message and str(store.root) in message and "\n" not in message
    assert "--resume" in message
    (run,) = store.runs()
    assert leftovers(run) == []  # no partial job file, no temporary file
    assert len(run.finished_jobs()) == 2
    assert run.metrics()["repetition"].nunique() == 1  # the two jobs of repetition 0, readable
    assert run.info()["id"] == run.id  # run.json intact (its last update failed as a whole)
    monkeypatch.undo()  # space is freed
    result = run_experiment(spec, store, workers=1, resume=run)
    assert result.run.info()["status"] == "finished" and len(run.finished_jobs()) == 6
    assert np.array_equal(values(reference), values(run.metrics()), equal_nan=True)


def test_disk_full_while_writing_a_job_names_the_job_file(toy_parquet, tmp_path, monkeypatch):
    """Only job files fail (the small status file still fits): the error names the job and its file."""
    real = store_mod._write_bytes
    seen = {"n": 0}

    def write(fh, data, path):
        if ".parquet." in path.name:
            seen["n"] += 1
            if seen["n"] == 2:
                raise OSError(errno.ENOSPC, "No space left on device")
        real(fh, data, path)

    monkeypatch.setattr(store_mod, "_write_bytes", write)
    store = RunStore(tmp_path / "runs")
    with pytest.raises(StoreError) as err:
        run_experiment(fault_spec(toy_parquet), store, workers=1)
    (run,) = store.runs()
    job = "y__w0__published__krls__r000"
    assert str(err.value) == (
        f"disk full while writing job {job} of run {run.id} to {run.jobs_dir / (job + '.parquet')} in the store "
        f"{store.root} (No space left on device); nothing partial was kept; free space and finish the run with "
        f"`enginebench run --resume {run.id}`"
    )
    assert run.info()["status"] == "interrupted" and run.info()["finished_jobs"] == 1
    assert run.finished_jobs() == {"y__w0__published__naive-mean__r000"} and leftovers(run) == []


def test_disk_full_at_the_command_line_is_one_error_line_and_exit_2(toy_parquet, tmp_path, monkeypatch):
    exp = exp_file(tmp_path, toy_parquet)
    store = tmp_path / "runs"
    full_disk_after(3, monkeypatch)
    result = CliRunner().invoke(cli, ["run", str(exp), "-j", "1", "-q", "--store", str(store)])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit)
    lines = result.output.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: disk full while writing ") and str(store) in lines[0]
    monkeypatch.undo()
    (run,) = RunStore(store).runs()
    assert len(run.finished_jobs()) == 3
    resumed = CliRunner().invoke(cli, ["run", "--resume", run.id, "-j", "1", "-q", "--store", str(store)])
    assert resumed.exit_code == 0, resumed.output
    assert len(run.finished_jobs()) == 6 and run.info()["status"] == "finished"


def test_a_run_folder_that_cannot_be_set_up_is_removed(tmp_path, monkeypatch):
    def write(fh, data, path):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(store_mod, "_write_bytes", write)
    store = RunStore(tmp_path / "runs")
    with pytest.raises(StoreError, match=r"^disk full while writing the run's config .*config\.toml in the store "):
        store.create("x", {"a": 1}, "0123456789", {}, 1)
    assert list(store.root.iterdir()) == [] and store.runs() == []


# ----------------------------------------------------------------------------- two writers
WRITER = textwrap.dedent('''
    import os, sys, time
    from pathlib import Path
    from enginebench.results.store import RunStore
    root, go, tag, n = sys.argv[1], Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
    while not go.exists():
        time.sleep(0.001)
    store = RunStore(root)
    for i in range(n):
        store.create("same-name", {"writer": tag, "i": i}, "abcdef0123", {"writer": tag}, 1)
''')


def test_two_processes_creating_runs_at_once_get_distinct_folders(tmp_path):
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    go = tmp_path / "go"
    root = tmp_path / "runs"
    procs = [subprocess.Popen([sys.executable, str(script), str(root), str(go), tag, "15"], cwd=tmp_path,
                              stderr=subprocess.PIPE) for tag in ("A", "B")]
    time.sleep(1.0)  # both interpreters up and waiting
    go.touch()
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, err.decode()[-800:]
    store = RunStore(root)
    runs = store.runs()
    assert len(runs) == 30 and len({r.id for r in runs}) == 30
    import tomllib

    seen = set()
    for r in runs:
        info, cfg, env = r.info(), tomllib.loads((r.path / "config.toml").read_text()), r.environment()
        assert info["id"] == r.id and env["writer"] == cfg["writer"]  # every file of a folder from one writer
        seen.add((cfg["writer"], cfg["i"]))
    assert seen == {(w, i) for w in "AB" for i in range(15)}  # nothing clobbered, nothing lost
    newest = max(runs, key=lambda r: r.info()["created_ns"])
    assert store.get("latest").id == newest.id
    assert [r.info()["created_ns"] for r in runs] == sorted(r.info()["created_ns"] for r in runs)


def test_latest_is_the_run_created_last_even_past_ten_runs_in_one_second(tmp_path, monkeypatch):
    """Ids of runs created in one second end in -1 ... -11; 'latest' must not sort them as text."""
    clock = {"ns": 1_700_000_000_000_000_000}

    def fake_ns():
        clock["ns"] += 1000
        return clock["ns"]

    monkeypatch.setattr(time, "time_ns", fake_ns)  # the store stamps run ids and created_ns with it
    store = RunStore(tmp_path)
    made = [store.create("burst", {}, "feedbeef00", {}, 1).id for _ in range(12)]
    assert made[0].endswith("-burst-feedbe") and made[11] == made[0] + "-11"
    assert store.get("latest").id == made[-1]
    assert [r.id for r in store.runs()] == made


def test_two_runs_of_one_experiment_at_once_in_one_store(toy_parquet, tmp_path):
    exp = exp_file(tmp_path, toy_parquet, repetitions=2)
    env = {**os.environ, "ENGINEBENCH_STORE": str(tmp_path / "runs")}
    cmd = [sys.executable, "-c", "from enginebench.cli.main import main; main()", "run", str(exp), "-j", "1", "-q"]
    procs = [subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for _ in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err.decode()[-800:]
    store = RunStore(tmp_path / "runs")
    a, b = store.runs()
    assert a.id != b.id
    for run in (a, b):
        assert run.info()["status"] == "finished" and len(run.finished_jobs()) == 4 and leftovers(run) == []
    assert np.array_equal(values(a.metrics()), values(b.metrics()), equal_nan=True)
    assert store.get("latest").id == b.id


# ----------------------------------------------------------------------------- damaged job files
@pytest.fixture
def finished_run(toy_parquet, tmp_path):
    spec = fault_spec(toy_parquet)
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    return spec, run


def test_a_truncated_job_file_is_refused_by_name_and_recomputed_on_resume(finished_run, tmp_path):
    spec, run = finished_run
    store = str(run.store)
    reference = values(run.metrics())
    victim = run.jobs_dir / "y__w0__published__krls__r001.parquet"
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    others = {p.name: p.stat().st_mtime_ns for p in run.job_files() if p != victim}
    for args in (["table", run.id, "--format", "csv"], ["runs", "show", run.id]):
        result = CliRunner().invoke(cli, [*args, "--store", store])
        assert result.exit_code == 2, result.output
        lines = result.output.splitlines()  # `runs show` prints the run's header before its metrics
        (line,) = [x for x in lines if x.startswith("error:")]
        assert line == lines[-1] and "Traceback" not in result.output
        assert line.startswith(f"error: run {run.id}: job file {victim} is damaged (")
        assert line.endswith(f"the other jobs are intact: `enginebench run --resume {run.id}` recomputes this one")
    assert victim.stem not in run.finished_jobs() and victim.stem in run.finished_jobs(verify=False)
    assert run.damaged_jobs()[victim.stem].startswith("Could not open Parquet input source")
    resumed = CliRunner().invoke(cli, ["run", "--resume", run.id, "-j", "1", "-q", "--store", store])
    assert resumed.exit_code == 0, resumed.output
    assert f"job file {victim.stem}.parquet was damaged (Could not open Parquet input source" in " ".join(resumed.output.split())
    assert run.damaged_jobs() == {}
    assert {p.name: p.stat().st_mtime_ns for p in run.job_files() if p != victim} == others  # untouched
    assert np.array_equal(values(run.metrics()), reference, equal_nan=True)
    assert CliRunner().invoke(cli, ["table", run.id, "--format", "csv", "--store", store]).exit_code == 0


def test_every_single_byte_garble_is_detected_or_harmless(finished_run):
    """Flip one byte at a time: the job is refused as damaged, or it reads back exactly as written.

    Job files carry Parquet page checksums, so a garbled value cannot pass as a result.
    """
    _, run = finished_run
    path = run.jobs_dir / "y__w0__published__naive-mean__r000.parquet"
    good = path.read_bytes()
    meta = run.job_meta(path.stem)
    detected = 0
    for pos in range(0, len(good), 5):
        bad = bytearray(good)
        bad[pos] ^= 0xFF
        path.write_bytes(bytes(bad))
        damaged = run.damaged_jobs()
        if path.stem in damaged:
            detected += 1
            with pytest.raises(StoreError, match="is damaged"):
                run.metrics()
            continue
        frame, back = run._read_job(path)
        assert back == meta, f"byte {pos}: metadata changed silently"
        path.write_bytes(good)
        assert frame.equals(run._read_job(path)[0]), f"byte {pos}: metric rows changed silently"
    path.write_bytes(good)
    assert detected > 0


def test_a_damaged_status_file_is_one_error_line(finished_run):
    _, run = finished_run
    (run.path / "run.json").write_text('{"id": "x", "status": ')
    result = CliRunner().invoke(cli, ["runs", "show", run.id, "--store", str(run.store)])
    assert result.exit_code == 2
    (line,) = result.output.splitlines()
    assert line.startswith(f"error: run {run.id}: run.json is not valid JSON (") and "the run folder is damaged" in line


# ----------------------------------------------------------------------------- damaged run folders
@pytest.mark.parametrize("damage, why", [
    (lambda p: (p / "config.toml").unlink(), "config.toml is missing"),
    (lambda p: (p / "config.toml").write_text("name = "), "config.toml is not valid TOML ("),
    (lambda p: (p / "environment.json").write_text("[1, 2]"), "environment.json does not hold a table of keys"),
    (lambda p: (p / "run.json").write_text("{"), "run.json is not valid JSON ("),
])
def test_one_damaged_run_is_listed_as_damaged_and_latest_skips_it(finished_run, damage, why):
    """A damaged run folder no longer stops `runs list` and `table latest` for the whole store."""
    import shutil

    _, good = finished_run
    store = str(good.store)
    newer = good.store / "29990101-000000-newer-abcdef"
    shutil.copytree(good.path, newer)
    info = json.loads((newer / "run.json").read_text())
    (newer / "run.json").write_text(json.dumps({**info, "id": newer.name, "created_ns": info["created_ns"] + 10**9}))
    damage(newer)
    listed = CliRunner().invoke(cli, ["runs", "list", "--store", store])
    assert listed.exit_code == 0, listed.output
    lines = listed.output.splitlines()  # a header, then one row per run
    assert lines[0].split()[:2] == ["id", "status"] and len(lines) == 3
    assert lines[1].split()[:2] == [good.id, "finished"]
    assert lines[2].split()[:2] == [newer.name, "damaged"] and why in lines[2]
    table = CliRunner().invoke(cli, ["table", "latest", "--format", "csv", "--store", store])
    assert table.exit_code == 0 and RunStore(store).get("latest").id == good.id
    shown = CliRunner().invoke(cli, ["runs", "show", newer.name, "--store", store])
    assert shown.exit_code == 2 and shown.output.count("\n") == 1
    assert shown.output.startswith(f"error: run {newer.name}: {why}") and "the run folder is damaged" in shown.output
    removed = CliRunner().invoke(cli, ["runs", "rm", newer.name, "--yes", "--store", store])
    assert removed.exit_code == 0 and not newer.exists()


def test_latest_when_every_run_is_damaged(finished_run):
    _, run = finished_run
    (run.path / "environment.json").unlink()
    out = CliRunner().invoke(cli, ["table", "latest", "--store", str(run.store)])
    assert out.exit_code == 2
    assert out.output == f"error: every run in {run.store} is damaged; 'enginebench runs list' says why\n"


# ----------------------------------------------------------------------------- one writer per run
HOLD = """
import sys, time
from enginebench.results.run_folder import Run
Run(__import__("pathlib").Path(sys.argv[1])).lock()
print("locked", flush=True)
time.sleep(600)
"""


def test_a_run_being_written_is_locked_against_a_second_writer_until_its_process_dies(toy_parquet, tmp_path):
    """Two writers of one run: the second gets one error line naming the run and the holder's pid."""
    spec = fault_spec(toy_parquet)
    store = RunStore(tmp_path / "runs")

    run = interrupt_after(spec, store, workers=1)
    assert run.info()["status"] == "interrupted" and not run.holds_lock()
    holder = subprocess.Popen([sys.executable, "-P", "-c", HOLD, str(run.path)], stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline().strip() == b"locked"
        for args in (["run", "--resume", run.id, "-j", "1", "-q"], ["runs", "rm", run.id, "--yes"]):
            out = CliRunner().invoke(cli, [*args, "--store", str(store.root)])
            assert out.exit_code == 2, out.output
            assert out.output == (f"error: run {run.id} is being written by another process (pid {holder.pid}, lock "
                                  f"{run.path / 'run.lock'}); wait for it to end (or stop it), then "
                                  f"`enginebench run --resume {run.id}` if it is unfinished\n")
        with pytest.raises(StoreError, match=f"pid {holder.pid}"):
            run_experiment(spec, store, workers=1, resume=run)  # the library refuses too
        assert len(run.finished_jobs()) == 2 and run.info()["status"] == "interrupted"
    finally:
        holder.kill()
        holder.wait()
    # the OS released the dead holder's lock: the run resumes at once
    out = CliRunner().invoke(cli, ["run", "--resume", run.id, "-j", "1", "-q", "--store", str(store.root)])
    assert out.exit_code == 0, out.output
    assert run.info()["status"] == "finished" and len(run.finished_jobs()) == 6 and not run.holds_lock()
    assert not (run.path / "run.lock").exists()  # the lock file lives only while a writer holds it


def test_a_refused_writer_leaves_the_store_as_it_was(finished_run):
    _, run = finished_run
    before = {p: p.read_bytes() for p in run.store.rglob("*") if p.is_file()}
    holder = subprocess.Popen([sys.executable, "-P", "-c", HOLD, str(run.path)], stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline().strip() == b"locked"
        with pytest.raises(StoreError, match="being written by another process"):
            run.update_info(note="x")
    finally:
        holder.kill()
        holder.wait()
    after = {p: p.read_bytes() for p in run.store.rglob("*") if p.is_file()}
    assert set(after) - set(before) == {run.path / "run.lock"}  # the dead holder's stale file, reused by the next
    run.update_info(note="x")
    assert not (run.path / "run.lock").exists() and run.info()["note"] == "x"


SLOW_PLUGIN = '''
import os, time
import numpy as np
from enginebench.api import Method

class SlowMean(Method):
    name = "slow-mean"
    family = "baseline"
    modes = frozenset({"static"})

    def fit(self, train, params, rng):
        with open(os.environ["SLOW_MEAN_LOG"], "a") as f:
            f.write("fit\\n")
        time.sleep(float(os.environ["SLOW_MEAN_SECONDS"]))
        return train.y.mean(0)

    def predict(self, fitted, data):
        return [np.tile(fitted, (len(s), 1)) for s in data.segments]
'''


def test_sigterm_stops_a_pool_run_without_running_its_queued_jobs(tmp_path, toy_parquet):
    """SIGTERM (a scheduler, `timeout`) ends the run at once: queued jobs are cancelled and busy workers
    stopped, not every remaining job computed for nobody before the process exits; the run resumes."""
    plugin, log, store = tmp_path / "slow.py", tmp_path / "fits.log", tmp_path / "runs"
    plugin.write_text(SLOW_PLUGIN)
    exp = tmp_path / "exp.toml"
    exp.write_text(f'name = "slow"\ndataset = "{toy_parquet}"\ntargets = ["y"]\nrepetitions = 16\n'
                   f'train_size = 50\n[selection]\nkind = "none"\n[methods.slow-mean]\n')
    env = {**os.environ, "SLOW_MEAN_LOG": str(log), "ENGINEBENCH_STORE": str(store)}
    cmd = [sys.executable, "-P", "-c", "from enginebench.cli.main import main; main()", "run", str(exp),
           "--plugin", str(plugin), "-j", "2", "-q"]
    # 2 s per fit: the 16 jobs need about 16 s on 2 workers, so a test process starved by a loaded
    # machine still signals long before they could all have started (the resume runs fast)
    proc = subprocess.Popen(cmd, env={**env, "SLOW_MEAN_SECONDS": "2"}, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        for _ in range(3000):  # until the first job is stored (minutes on a starved machine)
            if list(store.glob("*/jobs/*.parquet")) or proc.poll() is not None:
                break
            time.sleep(0.1)
        assert proc.poll() is None, proc.communicate()
        proc.terminate()
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    time.sleep(2.5)  # a worker left running would log more fits meanwhile
    started = log.read_text().count("fit")
    assert proc.returncode != 0
    assert started < 16, f"{started} of 16 fits ran after SIGTERM: the queued jobs were not cancelled"
    (run,) = RunStore(store).runs()
    done = len(list((run.path / "jobs").glob("*.parquet")))
    assert 1 <= done < 16
    assert f"interrupted: {done} of 16 jobs of run {run.id} are stored; finish it with `enginebench run --resume " \
           f"{run.id}`" in err.decode()
    resumed = subprocess.run([sys.executable, "-P", "-c", "from enginebench.cli.main import main; main()", "run",
                              "--resume", run.id, "--plugin", str(plugin), "-j", "2", "-q"],
                             env={**env, "SLOW_MEAN_SECONDS": "0.05"},
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert len(list((run.path / "jobs").glob("*.parquet"))) == 16


def test_a_run_resumed_by_other_code_says_so_and_counts_its_stored_jobs(toy_parquet, tmp_path, monkeypatch):
    """A resume records when and with which code it ran; ``runs show`` counts the job files (not a
    count left in run.json by an earlier part) and names a resume whose git commit differs."""
    from enginebench.experiments import environment

    store = RunStore(tmp_path / "runs")
    run = interrupt_after(fault_spec(toy_parquet), store, jobs=2, workers=1)
    made = run.environment()["git_commit"]
    monkeypatch.setattr(environment, "git_commit", lambda path=None: "f" * 40)

    def stop_at_four(done, total, job):
        if done == 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_experiment(fault_spec(toy_parquet), store, workers=1, resume=run, progress=stop_at_four)
    (part,) = run.info()["resumes"]
    assert part["git_commit"] == "f" * 40 and part["workers"] == 1 and part["at"].endswith("Z")
    out = CliRunner().invoke(cli, ["runs", "show", run.id, "--store", str(store.root)])
    assert out.exit_code == 0, out.output
    assert out.output.splitlines()[0].startswith(f"run {run.id}: interrupted (4/6 jobs, ")
    assert (f"resumed with other code: created with git {str(made)[:7]}, resumed {part['at']} with git fffffff: "
            "jobs of the two parts may differ") in out.output


def test_a_run_resumed_by_the_same_code_has_no_provenance_note(toy_parquet, tmp_path):
    store = RunStore(tmp_path / "runs")
    run = interrupt_after(fault_spec(toy_parquet), store, jobs=2, workers=1)
    run_experiment(fault_spec(toy_parquet), store, workers=1, resume=run)
    assert len(run.info()["resumes"]) == 1
    out = CliRunner().invoke(cli, ["runs", "show", run.id, "--store", str(store.root)])
    assert out.output.splitlines()[0].startswith(f"run {run.id}: finished (6/6 jobs, 0 failed)")
    assert "resumed with other code" not in out.output


def _children(pid: int) -> set[int]:
    """Processes whose parent is ``pid`` (from /proc)."""
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc to find the pool's workers")
def test_kill_9_of_a_pool_run_leaves_no_worker_running(tmp_path, toy_parquet):
    """The run's process killed outright (no handler runs): its pool workers notice their parent is gone and
    exit within seconds instead of computing queued jobs for nobody."""
    plugin, log, store = tmp_path / "slow.py", tmp_path / "fits.log", tmp_path / "runs"
    plugin.write_text(SLOW_PLUGIN)
    exp = tmp_path / "exp.toml"
    exp.write_text(f'name = "slow"\ndataset = "{toy_parquet}"\ntargets = ["y"]\nrepetitions = 16\n'
                   f'train_size = 50\n[selection]\nkind = "none"\n[methods.slow-mean]\n')
    env = {**os.environ, "SLOW_MEAN_LOG": str(log), "ENGINEBENCH_STORE": str(store), "SLOW_MEAN_SECONDS": "2"}
    cmd = [sys.executable, "-P", "-c", "from enginebench.cli.main import main; main()", "run", str(exp),
           "--plugin", str(plugin), "-j", "2", "-q"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(3000):  # until a worker has started a fit
            if (log.exists() and log.read_text()) or proc.poll() is not None:
                break
            time.sleep(0.1)
        workers = _children(proc.pid)
        assert proc.poll() is None and workers
        proc.kill()
        proc.wait(timeout=60)
        for _ in range(200):  # the watch polls every second; a fit in progress ends within 2 s
            alive = {w for w in workers if Path(f"/proc/{w}").exists()
                     and "Z" not in Path(f"/proc/{w}/stat").read_text().rsplit(")", 1)[1].split()[0]}
            if not alive:
                break
            time.sleep(0.1)
        assert not alive, f"{len(alive)} worker(s) still running 20 s after kill -9 of the run"
    finally:
        proc.kill()
