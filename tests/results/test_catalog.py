"""The run catalogue (results/catalog.py): entries, statuses, filters, tags and the fitted table."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from datetime import datetime, timedelta, timezone

import pytest

from enginebench.errors import SpecError, StoreError
from enginebench.results import catalog
from enginebench.results.catalog import Filters, edit_tags, entries, parse_since, parse_tags, select
from enginebench.results.store import RunStore
from helpers import stored_run

NOW = datetime.now(timezone.utc)


def _ns(when: datetime) -> int:
    return int(when.timestamp() * 1e9)


def _local(text: str) -> datetime:
    return datetime.fromisoformat(text).astimezone()  # a naive ISO time read as local time, as --since reads it


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> RunStore:
    """Five runs: alpha and beta (old, tagged), gamma (interrupted), delta (damaged), epsilon (killed while running)."""
    store = RunStore(tmp_path_factory.mktemp("catalog") / "runs")
    stored_run(store, "alpha", {"naive-mean": [1.0, 1.1], "krls": [0.5, 0.6]}, dataset="gas-turbine-emissions",
               created_ns=_ns(_local("2025-01-10T12:00")), tags={"owner": "ana", "stage": "dev"})
    stored_run(store, "beta", {"cascade": [0.7, 0.8]}, dataset="/data/x/toy.parquet", failed=1,
               created_ns=_ns(_local("2025-02-01T09:30")), tags={"owner": "bo"},
               method_options={"cascade": {"first": "arx", "second": "krls"}})
    stored_run(store, "gamma", {"krls": [0.4]}, dataset="/data/x/toy.parquet", status="interrupted", n_jobs=3,
               created_ns=_ns(NOW - timedelta(hours=5)), tags={"stage": "prod"})
    delta = stored_run(store, "delta", {"krls": [0.4]}, dataset="gas-turbine-emissions",
                       created_ns=_ns(NOW - timedelta(minutes=50)))
    (delta.path / "config.toml").unlink()
    killed = stored_run(store, "epsilon", {"krls": [0.4]}, status="running", n_jobs=4,
                        created_ns=_ns(NOW - timedelta(minutes=10)))
    killed.unlock()  # its process died: run.json still says running, nobody holds the lock
    return store


def _names(found) -> list[str]:
    return [e.name for e in found]


def test_entries_say_what_the_store_knows(store):
    by = {e.name: e for e in entries(store, NOW)}
    assert list(by) == ["alpha", "beta", "gamma", "delta", "epsilon"]  # oldest first
    assert (by["alpha"].status, by["alpha"].jobs_done, by["alpha"].jobs_total) == ("finished", 4, 4)
    assert by["alpha"].methods == ("naive-mean", "krls") and by["alpha"].tags == {"owner": "ana", "stage": "dev"}
    assert (by["beta"].status, by["beta"].failed_jobs) == ("failed", 1)  # finished, but a job failed
    assert by["beta"].used == ("cascade", "arx", "krls")
    assert (by["gamma"].status, by["gamma"].jobs_done, by["gamma"].jobs_total) == ("interrupted", 1, 3)
    assert by["delta"].status == "damaged" and by["delta"].damage == "config.toml is missing"
    assert abs((by["delta"].created - (NOW - timedelta(minutes=50))).total_seconds()) < 1e-3  # run.json is whole
    assert by["epsilon"].status == "interrupted"  # marked running, lock free: killed
    assert by["alpha"].created == _local("2025-01-10T12:00")


def test_a_run_whose_writer_is_alive_is_running_and_its_wall_time_grows(tmp_path):
    store = RunStore(tmp_path / "runs")
    run = stored_run(store, "live", {"krls": [0.4]}, status="running", n_jobs=2)
    started = run.info()["created_ns"]
    later = datetime.fromtimestamp(started / 1e9 + 90.0, timezone.utc)
    (e,) = entries(store, later)
    assert (e.status, e.jobs_done, e.jobs_total) == ("running", 1, 2)
    assert e.wall_s == pytest.approx(90.0, abs=1e-3)
    assert catalog.writer_pid(run) == str(__import__("os").getpid())
    run.update_info(status="finished", finished_jobs=1, failed_jobs=0)  # the session ends: its seconds are kept
    assert 0.0 < run.info()["wall_s"] <= (time.time_ns() - started) / 1e9
    assert entries(store)[0].status == "finished" and catalog.writer_pid(run) is None


@pytest.mark.parametrize("kwargs, expected", [
    ({}, ["alpha", "beta", "gamma", "delta", "epsilon"]),
    ({"dataset": "gas-turbine-emissions"}, ["alpha"]),   # delta's config is gone: its dataset is unknown
    ({"dataset": "toy.parquet"}, ["beta", "gamma"]),      # a dataset file by its name
    ({"dataset": "toy"}, ["beta", "gamma"]),              # ... or its stem
    ({"method": "krls"}, ["alpha", "beta", "gamma", "epsilon"]),  # beta's cascade uses krls as a stage
    ({"method": "arx"}, ["beta"]),
    ({"method": "naive-mean"}, ["alpha"]),
    ({"statuses": ["interrupted"]}, ["gamma", "epsilon"]),
    ({"statuses": ["finished", "failed"]}, ["alpha", "beta"]),
    ({"statuses": ["damaged"]}, ["delta"]),
    ({"statuses": ["running"]}, []),
    ({"tags": ["owner"]}, ["alpha", "beta"]),
    ({"tags": ["owner=ana"]}, ["alpha"]),
    ({"tags": ["stage"]}, ["alpha", "gamma"]),
    ({"tags": ["owner", "stage=dev"]}, ["alpha"]),        # every tag must match
    ({"tags": ["owner=bo", "stage"]}, []),
    ({"since": "2025-01-20"}, ["beta", "gamma", "delta", "epsilon"]),
    ({"since": "2025-02-01T09:30"}, ["beta", "gamma", "delta", "epsilon"]),  # from that minute on
    ({"since": "2025-02-01T09:31"}, ["gamma", "delta", "epsilon"]),
    ({"since": "6h"}, ["gamma", "delta", "epsilon"]),
    ({"since": "1h"}, ["delta", "epsilon"]),
    ({"since": "20m"}, ["epsilon"]),
    ({"since": "1w", "method": "krls", "statuses": ["interrupted"]}, ["gamma", "epsilon"]),
])
def test_each_filter_selects_exactly_the_expected_runs(store, kwargs, expected):
    found = select(entries(store, NOW), Filters.parse(now=NOW, **kwargs))
    assert _names(found) == expected


def test_parse_since():
    assert parse_since("2h", NOW) == NOW - timedelta(hours=2)
    assert parse_since("3d", NOW) == NOW - timedelta(days=3)
    assert parse_since("90s", NOW) == NOW - timedelta(seconds=90)
    assert parse_since("1.5w", NOW) == NOW - timedelta(days=10.5)
    assert parse_since("2025-03-04T05:06+00:00") == datetime(2025, 3, 4, 5, 6, tzinfo=timezone.utc)
    assert parse_since("2025-03-04") == datetime(2025, 3, 4).astimezone()  # local midnight


@pytest.mark.parametrize("kwargs, message", [
    ({"statuses": ["done"]}, "--status 'done' is not a run status; use one of finished, failed, running, interrupted, damaged"),
    ({"since": "yesterday"}, "--since 'yesterday' is neither an ISO date/time (2025-01-31, 2025-01-31T14:30) nor an age"),
    ({"since": "2h ago"}, "--since '2h ago' is neither"),
    ({"tags": ["=x"]}, "--tag '=x': the tag has no key; write KEY=VALUE"),
    ({"tags": [""]}, "--tag '': the tag has no key"),
])
def test_bad_filter_values_are_one_line(kwargs, message):
    with pytest.raises(SpecError) as err:
        Filters.parse(**kwargs)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_parse_tags_validates_keys():
    assert parse_tags(["owner=ana", "note=a=b", "empty=", "owner=bo"]) == {"owner": "bo", "note": "a=b", "empty": ""}
    for bad, message in [("owner", "--tag 'owner': write KEY=VALUE"), ("=v", "the tag has no key"),
                         (" k=v", "must be printable, without '=' or surrounding spaces"),
                         ("k\tx=v", "must be printable"), ("k=a\nb", "the value must be printable text")]:
        with pytest.raises(SpecError, match=message.replace("(", r"\(")):
            parse_tags([bad])


def test_tags_are_edited_in_run_json_but_never_in_the_config(tmp_path):
    store = RunStore(tmp_path / "runs")
    run = stored_run(store, "t", {"krls": [0.4]}, tags={"owner": "ana"})
    config_before = (run.path / "config.toml").read_bytes()
    assert edit_tags(run, add={"stage": "dev", "owner": "bo"}) == {"owner": "bo", "stage": "dev"}
    assert edit_tags(run, remove=["owner"]) == {"stage": "dev"}
    assert json.loads((run.path / "run.json").read_text())["tags"] == {"stage": "dev"}
    assert (run.path / "config.toml").read_bytes() == config_before and run.info()["config_hash"] == "000001t"
    with pytest.raises(StoreError, match=r"has no tag 'owner'; its tags: stage"):
        edit_tags(run, remove=["owner"])
    with pytest.raises(SpecError, match="no key"):
        edit_tags(run, add={"": "x"})
    assert not (run.path / "run.lock").exists()  # the edit took and released the lock


HOLD = """
import sys, time
from enginebench.results.run_folder import Run
Run(__import__("pathlib").Path(sys.argv[1])).lock()
print("locked", flush=True)
time.sleep(600)
"""


def test_a_run_being_written_keeps_its_tags_and_is_listed_running(tmp_path):
    store = RunStore(tmp_path / "runs")
    run = stored_run(store, "busy", {"krls": [0.4]}, status="running", n_jobs=3)
    run.unlock()
    holder = subprocess.Popen([sys.executable, "-P", "-c", HOLD, str(run.path)], stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline().strip() == b"locked"
        assert catalog.writer_pid(run) == str(holder.pid)
        assert entries(store)[0].status == "running"
        with pytest.raises(StoreError) as err:
            edit_tags(run, add={"k": "v"})
        assert str(err.value) == (f"run {run.id} is being written by another process (pid {holder.pid}); "
                                  "change its tags once that process has ended")
        assert run.info()["tags"] == {}
    finally:
        holder.kill()
        holder.wait()
    assert entries(store)[0].status == "interrupted"  # its writer died


def test_damaged_run_tags_are_refused(store):
    (delta,) = [r for r in store.runs() if r.id.split("-")[2] == "delta"]
    with pytest.raises(StoreError, match="is damaged \\(config.toml is missing\\); its tags cannot be changed"):
        edit_tags(delta, add={"k": "v"})


def test_table_has_a_header_fits_the_width_and_never_cuts_the_id(store):
    found = entries(store, NOW)
    for width in (60, 80, 100, 200):
        lines = catalog.catalog_text(found, width).splitlines()
        assert lines[0].split()[:3] == ["id", "status", "jobs"]
        assert len(lines) == 1 + len(found)
        for line, e in zip(lines[1:], found):
            assert line.split()[0] == e.id
            if e.damage is None:
                assert len(line) <= width, (width, line)
            else:
                assert line.split()[1] == "damaged" and line.endswith(e.damage)  # the reason, whole
    wide = catalog.catalog_text(found, 200).splitlines()
    assert wide[0].split() == ["id", "status", "jobs", "created", "wall", "name", "dataset", "methods", "tags"]
    assert "owner=ana,stage=dev" in wide[1] and "naive-mean,krls" in wide[1] and "2025-01-10 12:00" in wide[1]
    assert wide[2].split()[1:3] == ["failed", "2/2"] and wide[3].split()[1:3] == ["interrupted", "1/3"]
    narrow = catalog.catalog_text(found, 80).splitlines()
    assert "name" not in narrow[0].split() and "…" in narrow[1]  # the least useful column goes, others are trimmed


def test_records_for_scripts(store):
    records = catalog.catalog_records(entries(store, NOW))
    alpha = records[0]
    assert alpha["methods"] == ["naive-mean", "krls"] and alpha["tags"] == {"owner": "ana", "stage": "dev"}
    assert alpha["created"].startswith("2025-01-10T12:00:00") and (alpha["jobs_done"], alpha["jobs_total"]) == (4, 4)
    assert records[3]["status"] == "damaged" and records[3]["damage"] == "config.toml is missing"
    csv = catalog.catalog_csv(entries(store, NOW)).splitlines()
    assert csv[0].startswith("id,name,dataset,methods,status,jobs_done,jobs_total,failed_jobs,created,wall_s,tags")
    assert csv[1].endswith(",owner=ana;stage=dev,") and '"naive-mean,krls"' in csv[1]


def test_tagging_a_killed_run_leaves_it_unlocked(tmp_path):
    store = RunStore(tmp_path / "runs")
    killed = stored_run(store, "killed", {"krls": [0.4]}, status="running", n_jobs=2)
    killed.unlock()
    assert edit_tags(killed, add={"k": "v"}) == {"k": "v"}
    assert not killed.holds_lock() and not (killed.path / "run.lock").exists()
    (e,) = entries(store)
    assert (e.status, e.tags) == ("interrupted", {"k": "v"})
    (killed.path / "environment.json").unlink()
    line = catalog.catalog_text(entries(store), 20).splitlines()[1]
    assert line == f"{killed.id}  damaged  environment.json is missing"  # narrower than the id: still whole
