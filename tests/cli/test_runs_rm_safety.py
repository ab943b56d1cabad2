"""``runs rm`` (and tag/untag) touch only runs of the store: a path outside it, ``.``, and an empty reference
(an unset ``$RUN``) are refused with one line and nothing is deleted."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.results.store import RunStore
from helpers import stored_run


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def world(tmp_path):
    store = RunStore(tmp_path / "store")
    run = stored_run(store, "only", {"naive-mean": [1.0]})
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "run.json").write_text('{"id": "mine"}')  # looks like a run, is the user's
    (foreign / "notes.txt").write_text("my thesis")
    return store, run, foreign


@pytest.mark.parametrize("args", [["runs", "rm", ".", "--yes"], ["runs", "tag", ".", "k=v"],
                                  ["runs", "untag", ".", "k"]])
def test_a_folder_outside_the_store_is_refused(world, args, monkeypatch):
    store, run, foreign = world
    before, kept = _tree(foreign), _tree(run.path)
    monkeypatch.chdir(foreign)
    out = CliRunner().invoke(cli, [*args, "--store", str(store.root)])
    assert out.exit_code == 2 and out.output.startswith("error: .: ")
    assert "is not a run folder of the store" in out.output and len(out.output.strip().splitlines()) == 1
    assert _tree(foreign) == before and _tree(run.path) == kept


def test_an_absolute_path_outside_the_store_is_refused(world):
    store, run, foreign = world
    out = CliRunner().invoke(cli, ["runs", "rm", str(foreign), "--yes", "--store", str(store.root)])
    assert out.exit_code == 2 and "is not a run folder of the store" in out.output
    assert (foreign / "notes.txt").read_text() == "my thesis"


@pytest.mark.parametrize("ref", ["", "  "])
def test_an_empty_reference_deletes_nothing(world, ref):
    store, run, _ = world
    out = CliRunner().invoke(cli, ["runs", "rm", ref, "--yes", "--store", str(store.root)])
    assert out.exit_code == 2 and out.output.startswith("error: an empty run reference (an unset variable")
    assert run.path.is_dir() and [r.id for r in store.runs()] == [run.id]


def test_runs_of_the_store_are_deleted_by_id_or_by_their_path(world, tmp_path):
    store, run, _ = world
    other = stored_run(store, "second", {"naive-mean": [2.0]})
    by_path = CliRunner().invoke(cli, ["runs", "rm", str(other.path), "--yes", "--store", str(store.root)])
    assert by_path.exit_code == 0 and not other.path.exists()
    by_id = CliRunner().invoke(cli, ["runs", "rm", run.id, "--yes", "--store", str(store.root)])
    assert by_id.exit_code == 0 and by_id.output.strip() == f"deleted {run.id}" and store.runs() == []
    assert os.listdir(store.root) == []


def test_a_symlink_in_the_store_to_a_folder_elsewhere_is_refused(world):
    store, run, foreign = world
    link = store.root / "linked"
    link.symlink_to(foreign, target_is_directory=True)
    out = CliRunner().invoke(cli, ["runs", "rm", "linked", "--yes", "--store", str(store.root)])
    assert out.exit_code == 2 and (foreign / "notes.txt").exists()


def test_a_run_folder_without_run_json_is_listed_as_damaged_and_not_deleted(world):
    import time

    store, run, _ = world
    broken = store.root / "20260101-000000-half-abcdef"
    (broken / "jobs").mkdir(parents=True)
    (broken / "config.toml").write_text('name = "half"\n')
    old = time.time() - 3600
    os.utime(broken, (old, old))
    listed = CliRunner().invoke(cli, ["runs", "list", "--store", str(store.root)])
    assert listed.exit_code == 0 and "damaged" in listed.output and "run.json is missing" in listed.output
    latest = CliRunner().invoke(cli, ["runs", "show", "latest", "--store", str(store.root)])
    assert latest.exit_code == 0 and run.id in latest.output  # latest skips the damaged folder
    out = CliRunner().invoke(cli, ["runs", "rm", broken.name, "--yes", "--store", str(store.root)])
    assert out.exit_code == 2 and "has no run.json" in out.output and (broken / "config.toml").exists()
    fresh = store.root / "20991231-000000-new-abcdef"  # being created right now: not listed
    (fresh / "jobs").mkdir(parents=True)
    listed = CliRunner().invoke(cli, ["runs", "list", "--store", str(store.root)])
    assert fresh.name not in listed.output
