"""Stored selection tables: one file per job beside the job file, verified, damage reported like a damaged job;
the run-level grid-edge note under ``enginebench table``."""

from __future__ import annotations

import errno
import shutil

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.errors import StoreError
from enginebench.experiments.jobs import Job, selection_frame
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.selection import SelectionTable
from enginebench.results import atomic as store_mod  # the store writes every file through atomic._write_bytes
from enginebench.results.job_files import SELECTION_COLUMNS, SELECTION_META
from enginebench.results.notes import edge_note_lines
from enginebench.results.store import RunStore
from helpers import toy_spec

JOB = Job("y", 0.0, "published", "krls", 1)
ROWS = pd.DataFrame({"method": ["krls"], "split": ["test"], "metric": ["mae"], "value": [0.5]})


def table_frame() -> pd.DataFrame:
    grid = [{"gamma": g, "lambda": lam} for g in (0.1, 1.0) for lam in (0.01, 0.1, 1.0)]
    scores = np.arange(12, dtype=float).reshape(6, 2) / 7.0
    return selection_frame(SelectionTable(grid, scores, "mae", 4).frame(), JOB)


@pytest.fixture
def run(tmp_path):
    made = RunStore(tmp_path / "runs").create("sel", {"dataset": "toy"}, "abc123", {}, 2)
    made.write_job(JOB.key, ROWS, {"status": "ok", "method": "krls", SELECTION_META: table_frame()})
    made.write_job("naive", ROWS.assign(method="naive-mean"), {"status": "ok", "method": "naive-mean"})
    made.unlock()
    return made


def leftovers(run) -> list[str]:
    return sorted(p.name for p in run.path.rglob(".*"))


def test_a_stored_table_reads_back_with_the_job_coordinates(run):
    back = run.selection_table()
    expected = table_frame()
    assert list(back.columns) == ["target", "window", "split", "method", "repetition", "point", "param:gamma",
                                  "param:lambda", "resample", "score", "criterion", "chosen"]
    assert len(back) == 12 and set(back["split"]) == {"published"} and set(back["repetition"]) == {1}
    assert np.array_equal(back["score"].to_numpy(), expected["score"].to_numpy())  # float64, bit for bit
    assert back.loc[back["chosen"], "point"].tolist() == [4, 4]
    pd.testing.assert_frame_equal(run.selection_table(JOB.key), back, check_dtype=False)
    assert run.selection_table("naive").empty  # a method with nothing to select stores no table
    assert sorted(p.name for p in run.selection_dir.iterdir()) == [f"{JOB.key}.parquet"]
    assert run.job_meta(JOB.key)["selection_file"]["rows"] == 12 and SELECTION_META not in run.job_meta(JOB.key)
    assert run.damaged_jobs() == {} and run.finished_jobs() == {JOB.key, "naive"}


def test_a_run_without_tables_gives_the_empty_frame_with_the_columns(tmp_path):
    old = RunStore(tmp_path / "runs").create("old", {"dataset": "toy"}, "abc123", {}, 1)
    old.write_job("j", ROWS, {"status": "ok", "method": "krls", "search": {"grid_size": 9}})  # as runs made before
    table = old.selection_table()
    assert table.empty and list(table.columns) == list(SELECTION_COLUMNS)
    assert edge_note_lines(old.job_metas().values()) == []
    with pytest.raises(StoreError, match=f"run {old.id}: job nope has no file "):
        old.selection_table("nope")


@pytest.mark.parametrize("damage, why", [
    (lambda p: p.unlink(), "is missing"),
    (lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]), "does not match the SHA-256 recorded in the job file"),
    (lambda p: p.write_bytes(bytes([p.read_bytes()[0]]) + b"\x00" + p.read_bytes()[2:]),
     "does not match the SHA-256 recorded in the job file"),
])
def test_a_damaged_table_makes_its_job_damaged_and_is_refused_by_name(run, damage, why):
    path = run.selection_dir / f"{JOB.key}.parquet"
    damage(path)
    assert run.damaged_jobs() == {JOB.key: f"its selection table {path} {why}"}
    assert run.finished_jobs() == {"naive"} and JOB.key in run.finished_jobs(verify=False)
    with pytest.raises(StoreError) as err:
        run.selection_table()
    assert str(err.value) == (f"run {run.id}: job {JOB.key}: its selection table {path} {why}; its metrics are intact: "
                              f"`enginebench run --resume {run.id}` recomputes the job")
    assert len(run.metrics()) == 2  # the metric rows stay readable
    resume = run.prepare_resume()
    assert resume.finished == {"naive"} and resume.damaged == {JOB.key: f"its selection table {path} {why}"}
    run.unlock()


def test_a_failed_table_write_removes_the_job_file(run, monkeypatch):
    real = store_mod._write_bytes

    def write(fh, data, path):
        if path.parent.name == "selection":
            real(fh, data[: len(data) // 2], path)
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fh, data, path)

    monkeypatch.setattr(store_mod, "_write_bytes", write)
    key = "y__w0__published__krls__r002"
    with pytest.raises(StoreError) as err:
        run.write_job(key, ROWS, {"status": "ok", SELECTION_META: table_frame()})
    assert str(err.value).startswith(f"disk full while writing the selection table of job {key} of run {run.id} to "
                                     f"{run.selection_dir / (key + '.parquet')} in the store {run.store} ")
    assert key not in run.finished_jobs(verify=False) and leftovers(run) == []
    assert run.finished_jobs() == {JOB.key, "naive"}


def test_a_job_written_again_without_a_table_drops_the_old_one(run):
    run.write_job(JOB.key, ROWS, {"status": "failed", "method": "krls"})
    assert not (run.selection_dir / f"{JOB.key}.parquet").exists() and run.selection_table().empty
    assert run.damaged_jobs() == {}


# -- the grid-edge note -------------------------------------------------------------------------------
def meta(method, target="y", split="published", rep=0, **edges):
    return {"method": method, "target": target, "window": 0.0, "split": split, "repetition": rep,
            "search": {"grid_edges": {name: {"edge": e, "lower": 1e-4, "upper": 1e4, "warn": warn, "option": opt}
                                      for name, (e, warn, opt) in edges.items()}}}


def test_the_edge_note_counts_jobs_per_method_and_parameter():
    metas = [meta("krls", rep=r, gamma=("upper", True, "gamma_grid"), lam=(None, True, "lambda_grid")) for r in range(8)]
    assert edge_note_lines(metas) == [
        "grid edge: krls: gamma at the upper edge of its grid (10000) in 8 of 8 repetitions: widen gamma_grid"]
    mixed = [meta("m", target=t, rep=0, degree=("lower", False, "degrees"), alpha=(e, True, None))
             for t, e in (("a", "lower"), ("b", None), ("c", "lower"))]
    mixed.append({"method": "old", "search": {"grid_size": 3}})  # a job stored before the record: ignored
    assert edge_note_lines(mixed) == [  # the degree's lower edge is not worth a warning (its method's rule)
        "grid edge: m: alpha at the lower edge of its grid (0.0001) in 2 of 3 jobs: widen its grid"]


@pytest.fixture(scope="module")
def narrow_run(tmp_path_factory):
    from helpers import make_toy

    from enginebench.datasets.io import write_dataset

    root = tmp_path_factory.mktemp("narrow")
    data = write_dataset(make_toy(), root / "toy.parquet")
    spec = toy_spec(data, methods={"naive-mean": {}, "krls": {"gamma_grid": [-4, -3, 3], "lambda_grid": [-1, 1, 3]}})
    from enginebench.methods.krls import KRLS

    with pytest.MonkeyPatch.context() as patch:  # krls as a plugin declaring no bounds: its grid is not extended
        patch.setattr(KRLS, "search_bounds", lambda self, data: {})
        return run_experiment(spec, RunStore(root / "runs"), workers=1).run


def test_table_notes_a_grid_that_is_too_narrow(narrow_run):
    result = CliRunner().invoke(cli, ["table", narrow_run.id, "--store", str(narrow_run.store), "--format", "md"])
    assert result.exit_code == 0, result.output
    assert ("grid edge: krls: gamma at the upper edge of its grid (0.001) in 3 of 3 repetitions: widen gamma_grid"
            in result.output.splitlines())
    table = narrow_run.selection_table()
    assert len(table) == 3 * 9 * 2 and set(table["method"]) == {"krls"} and set(table["criterion"]) == {"mae"}
    chosen = table[table["chosen"]]
    assert np.allclose(chosen["param:gamma"], 1e-3)
    for _, rows in table.groupby("repetition"):  # the chosen point has the lowest mean score of its job
        mean = rows.groupby("point")["score"].mean()
        assert set(rows.loc[rows["chosen"], "point"]) == {int(mean.idxmin())}


def test_resume_recomputes_only_the_job_whose_table_is_damaged(narrow_run, tmp_path, monkeypatch):
    from enginebench.methods.krls import KRLS

    monkeypatch.setattr(KRLS, "search_bounds", lambda self, data: {})  # as the run was made (narrow_run)
    store = tmp_path / "runs"
    shutil.copytree(narrow_run.store, store)
    run = RunStore(store).get(narrow_run.id)
    reference = run.selection_table()
    victim = run.selection_dir / "y__w0__published__krls__r001.parquet"
    victim.write_bytes(victim.read_bytes()[:-20])
    others = {p.name: p.stat().st_mtime_ns for p in run.job_files() if p.stem != victim.stem}
    assert list(run.damaged_jobs()) == [victim.stem]
    resumed = CliRunner().invoke(cli, ["run", "--resume", run.id, "-j", "1", "-q", "--store", str(store)])
    assert resumed.exit_code == 0, resumed.output
    said = f"job file {victim.name} was damaged (its selection table {victim} does not match the SHA-256"
    assert "".join(said.split()) in "".join(resumed.output.split())  # rich may wrap the long path anywhere
    assert run.damaged_jobs() == {} and len(run.finished_jobs()) == 6
    assert {p.name: p.stat().st_mtime_ns for p in run.job_files() if p.stem != victim.stem} == others
    pd.testing.assert_frame_equal(run.selection_table(), reference)  # recomputed exactly


def test_runs_show_and_both_reports_carry_the_grid_edge_note(narrow_run, tmp_path):
    """One list of notes under every view of a run (``results.notes.run_note_lines``), the grid-edge note included."""
    import html

    from enginebench.reports.interactive import plotly_available, write_interactive_report
    from enginebench.reports.static import write_report

    line = "grid edge: krls: gamma at the upper edge of its grid (0.001) in 3 of 3 repetitions: widen gamma_grid"
    shown = CliRunner().invoke(cli, ["runs", "show", narrow_run.id, "--store", str(narrow_run.store)])
    assert shown.exit_code == 0, shown.output
    assert "  " + line in shown.output.splitlines()
    page = write_report(narrow_run, tmp_path / "rep", figures=False).index.read_text()
    assert f"<li class=\"note\">{html.escape(line)}</li>" in page
    if plotly_available():
        interactive = write_interactive_report(narrow_run, tmp_path / "rep.html", figures=False).path.read_text()
        assert f"<li class=\"note\">{html.escape(line)}</li>" in interactive


def test_resume_note_names_changed_packages_and_commits_only_when_they_differ():
    from enginebench.results.notes import resume_note_lines

    env = {"git_commit": "a" * 40, "packages": {"numpy": "2.3.5", "scipy": "1.17.1"}}
    same = {"at": "2026-01-02T03:04:05Z", "git_commit": "a" * 40, "packages": {"numpy": "2.3.5", "scipy": "1.17.1"}}
    newer = {"at": "2026-01-03T00:00:00Z", "git_commit": "a" * 40, "packages": {"numpy": "2.4.0", "scipy": "1.17.1"}}
    assert resume_note_lines({}, env) == []
    assert resume_note_lines({"resumes": [same]}, env) == []
    assert resume_note_lines({"resumes": [same, newer]}, env) == [
        "resumed with other code: created with git aaaaaaa, resumed 2026-01-03T00:00:00Z with git aaaaaaa "
        "(numpy 2.3.5 -> 2.4.0): jobs of the two parts may differ"]
