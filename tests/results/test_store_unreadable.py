"""One unreadable run folder does not break `runs list` or `table latest` for the whole store (issue 32, item 8).

Tests run as root, where ``chmod 000`` stops no read: an unreadable file is made here as a
folder or a link loop in its place, bytes that are not UTF-8, or (permission denied) by
making every read under the folder raise ``PermissionError`` as the kernel would.
"""

from __future__ import annotations

import builtins
import io
import json
import os
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.results.store import RunStore
from helpers import stored_run


def _deny(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """As for a folder of mode 000: listing ``folder`` and every stat, listing and open of a path inside it fail
    with EACCES (the folder itself can still be stat'ed)."""
    inside = str(folder) + os.sep

    def guard(fn, itself: bool):
        def wrapped(path, *args, **kwargs):
            text = os.fspath(path) if isinstance(path, (str, os.PathLike)) else ""
            if text.startswith(inside) or itself and text == str(folder):
                raise PermissionError(13, "Permission denied", text)
            return fn(path, *args, **kwargs)
        return wrapped

    for module, name in ((os, "stat"), (os, "lstat"), (os, "listdir"), (os, "scandir"), (os, "open"),
                         (io, "open"), (builtins, "open")):
        monkeypatch.setattr(module, name, guard(getattr(module, name), name in ("listdir", "scandir")))


def _run_json_folder(p: Path) -> None:
    (p / "run.json").unlink()
    (p / "run.json").mkdir()


def _run_json_loop(p: Path) -> None:
    (p / "run.json").unlink()
    (p / "run.json").symlink_to("run.json")


def _jobs_a_file(p: Path) -> None:
    shutil.rmtree(p / "jobs")
    (p / "jobs").write_text("x")


DAMAGES = {
    "run-json-a-folder": (_run_json_folder, "run.json is unreadable ([Errno 21] Is a directory: '{path}/run.json')"),
    "run-json-a-link-loop": (_run_json_loop,
                             "run.json is unreadable ([Errno 40] Too many levels of symbolic links: '{path}/run.json')"),
    "run-json-not-utf8": (lambda p: (p / "run.json").write_bytes(b'{"id": "\xff"}'),
                          "run.json is unreadable ('utf-8' codec can't decode byte 0xff in position 8: invalid start "
                          "byte)"),
    "run-json-not-json": (lambda p: (p / "run.json").write_text("{"),
                          "run.json is not valid JSON (Expecting property name enclosed in double quotes: line 1 "
                          "column 2 (char 1))"),
    "config-a-folder": (lambda p: ((p / "config.toml").unlink(), (p / "config.toml").mkdir()),
                        "config.toml is unreadable ([Errno 21] Is a directory: '{path}/config.toml')"),
    "environment-not-utf8": (lambda p: (p / "environment.json").write_bytes(b"\xff"),
                             "environment.json is unreadable ('utf-8' codec can't decode byte 0xff in position 0: "
                             "invalid start byte)"),
    "jobs-a-file": (_jobs_a_file, "jobs/ is not a folder"),
    "jobs-missing": (lambda p: shutil.rmtree(p / "jobs"), "jobs/ is missing"),
}


@pytest.fixture
def store(tmp_path) -> tuple[RunStore, list]:
    rs = RunStore(tmp_path / "runs")
    runs = [stored_run(rs, name, {"naive-mean": [1.0, 2.0]}, created_ns=k * 10**18)
            for k, name in enumerate(("old", "middle", "new"), start=1)]
    return rs, runs


def _listed(rs: RunStore) -> dict[str, dict]:
    out = CliRunner().invoke(cli, ["runs", "list", "--format", "json", "--store", str(rs.root)])
    assert out.exit_code == 0, out.output
    return {e["id"]: e for e in json.loads(out.output)}


@pytest.mark.parametrize("which", [1, 2], ids=["middle", "newest"])
@pytest.mark.parametrize("damage", list(DAMAGES), ids=list(DAMAGES))
def test_an_unreadable_run_is_listed_as_damaged_with_its_reason_and_the_others_work(store, damage, which):
    rs, runs = store
    fn, why = DAMAGES[damage]
    bad = runs[which]
    fn(bad.path)
    listed = _listed(rs)
    assert set(listed) == {r.id for r in runs}
    assert listed[bad.id]["status"] == "damaged" and listed[bad.id]["damage"] == why.format(path=bad.path)
    assert [listed[r.id]["status"] for r in runs if r is not bad] == ["finished", "finished"]
    term = CliRunner().invoke(cli, ["runs", "list", "--width", "300", "--store", str(rs.root)])
    assert term.exit_code == 0 and why.format(path=bad.path) in term.output
    table = CliRunner().invoke(cli, ["table", "latest", "--format", "csv", "--store", str(rs.root)])
    newest_whole = runs[2] if which == 1 else runs[1]
    assert table.exit_code == 0, table.output
    assert RunStore(rs.root).get("latest").id == newest_whole.id


def test_a_run_folder_this_process_may_not_read_is_listed_as_damaged(store, monkeypatch):
    rs, runs = store
    bad = runs[2]
    _deny(monkeypatch, bad.path)
    listed = _listed(rs)
    assert listed[bad.id]["status"] == "damaged"
    assert listed[bad.id]["damage"] == f"run.json is unreadable ([Errno 13] Permission denied: '{bad.path}/run.json')"
    assert listed[bad.id]["jobs_done"] == 0
    assert [listed[r.id]["status"] for r in runs[:2]] == ["finished", "finished"]
    table = CliRunner().invoke(cli, ["table", "latest", "--format", "csv", "--store", str(rs.root)])
    assert table.exit_code == 0, table.output
    assert RunStore(rs.root).get("latest").id == runs[1].id
    shown = CliRunner().invoke(cli, ["runs", "show", bad.id, "--store", str(rs.root)])
    assert shown.exit_code == 2 and shown.output == (
        f"error: run {bad.id}: run.json is unreadable ([Errno 13] Permission denied: '{bad.path}/run.json'); the run "
        f"folder is damaged (`enginebench runs rm {bad.id}` removes it)\n")


def test_a_run_whose_jobs_folder_may_not_be_read_is_damaged(store, monkeypatch):
    rs, runs = store
    bad = runs[2]
    _deny(monkeypatch, bad.jobs_dir)
    listed = _listed(rs)
    assert listed[bad.id]["damage"] == f"jobs/ is unreadable ([Errno 13] Permission denied: '{bad.jobs_dir}')"
    assert RunStore(rs.root).get("latest").id == runs[1].id


def test_a_damaged_jobs_folder_is_named_by_table_and_runs_show_not_called_empty(store):
    rs, runs = store
    bad = runs[2]
    _jobs_a_file(bad.path)
    expected = (f"error: run {bad.id}: jobs/ is not a folder; the run folder is damaged "
                f"(`enginebench runs rm {bad.id}` removes it)\n")
    for verb in (["table", bad.id], ["runs", "show", bad.id]):
        out = CliRunner().invoke(cli, [*verb, "--store", str(rs.root)])
        assert out.exit_code == 2 and out.output == expected, out.output
