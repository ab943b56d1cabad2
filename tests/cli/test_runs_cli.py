"""`runs list` (header, filters, formats), `run --tag`, `runs tag/untag` and `compare` of several runs."""

from __future__ import annotations

import io
import json
import re
import time

import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.results.compare import compare_runs, num
from enginebench.results.store import RunStore
from helpers import stored_run


@pytest.fixture
def invoke(tmp_path, monkeypatch):
    monkeypatch.setenv("ENGINEBENCH_DATA", str(tmp_path / "data"))
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    runner = CliRunner()
    return lambda *args: runner.invoke(cli, [str(a) for a in args])


@pytest.fixture
def three(tmp_path):
    """Three stored runs: a (reference), b (paired with a, other values), c (other seed; m3 and target z only in c,
    m2 only in a and b)."""
    store = RunStore(tmp_path / "runs")
    now = time.time_ns()
    a = stored_run(store, "a", {"m1": [1.0, 1.1, 0.9, 1.0], "m2": [2.0, 2.2, 1.9, 2.1]}, created_ns=now - 3 * 10**9,
                   tags={"owner": "ana"})
    b = stored_run(store, "b", {"m1": [1.5, 1.7, 1.4, 1.6], "m2": [2.0, 2.1, 1.9, 2.1]}, created_ns=now - 2 * 10**9,
                   tags={"owner": "bo", "stage": "dev"})
    c = stored_run(store, "c", {"m1": [0.5, 0.6, 0.4, 0.5], "m3": [3.0, 3.1, 3.2, 3.0]}, seed=2, targets=("y", "z"),
                   created_ns=now - 10**9, status="interrupted", dataset="other")
    return a, b, c


def test_runs_list_has_a_header_and_filters(invoke, three):
    a, b, c = three
    out = invoke("runs", "list", "--width", "80")
    assert out.exit_code == 0, out.output
    lines = out.output.splitlines()
    assert lines[0].split()[:3] == ["id", "status", "jobs"] and len(lines) == 4
    assert [ln.split()[0] for ln in lines[1:]] == [a.id, b.id, c.id] and all(len(ln) <= 80 for ln in lines)
    for args, expected in [(["--tag", "owner"], [a, b]), (["--tag", "owner=bo"], [b]), (["--tag", "owner", "--tag", "stage"], [b]),
                           (["--status", "interrupted"], [c]), (["--dataset", "other"], [c]), (["--method", "m2"], [a, b]),
                           (["--since", "1h"], [a, b, c]), (["--since", "2099-01-01"], [])]:
        out = invoke("runs", "list", *args)
        assert out.exit_code == 0, out.output
        listed = [ln.split()[0] for ln in out.output.splitlines()[1:]] if expected else []
        assert listed == [r.id for r in expected], args
        if not expected:
            assert out.output.startswith("no run in ") and "matches the filters" in out.output
    records = json.loads(invoke("runs", "list", "--format", "json", "--tag", "owner").output)
    assert [r["id"] for r in records] == [a.id, b.id] and records[1]["tags"] == {"owner": "bo", "stage": "dev"}
    frame = pd.read_csv(io.StringIO(invoke("runs", "list", "--format", "csv").output))
    assert list(frame["status"]) == ["finished", "finished", "interrupted"] and list(frame["jobs_done"]) == [8, 8, 8]


@pytest.mark.parametrize("args, message", [
    (["--status", "done"], "error: --status 'done' is not a run status; use one of finished, failed, running, "
                           "interrupted, damaged"),
    (["--since", "last week"], "error: --since 'last week' is neither an ISO date/time (2025-01-31, "
                               "2025-01-31T14:30) nor an age (30m, 2h, 3d, 1w)"),
    (["--tag", "=ana"], "error: --tag '=ana': the tag has no key; write KEY=VALUE (e.g. --tag owner=ana)"),
])
def test_bad_filters_exit_2_with_one_line(invoke, three, args, message):
    out = invoke("runs", "list", *args)
    assert out.exit_code == 2 and out.output == message + "\n"


def test_runs_tag_and_untag(invoke, three):
    a, _, _ = three
    out = invoke("runs", "tag", a.id, "stage=prod", "owner=eve")
    assert out.exit_code == 0 and out.output == f"run {a.id}: tags owner=eve, stage=prod\n"
    assert [ln.split()[0] for ln in invoke("runs", "list", "--tag", "stage=prod").output.splitlines()[1:]] == [a.id]
    out = invoke("runs", "untag", a.id, "owner")
    assert out.exit_code == 0 and out.output == f"run {a.id}: tags stage=prod\n"
    out = invoke("runs", "untag", a.id, "owner")
    assert out.exit_code == 2 and out.output == f"error: run {a.id} has no tag 'owner'; its tags: stage\n"
    out = invoke("runs", "tag", a.id, "novalue")
    assert out.exit_code == 2 and out.output == "error: runs tag 'novalue': write KEY=VALUE (e.g. --tag owner=ana)\n"


def test_run_tag_is_stored_shown_and_filterable_but_not_in_the_config(invoke, tmp_path, toy_parquet):
    exp = tmp_path / "exp.toml"
    exp.write_text(f'dataset = "{toy_parquet}"\ntargets = ["y"]\nrepetitions = 2\ntrain_size = 60\n'
                   '[selection]\nkind = "none"\n[methods.naive-mean]\n')
    out = invoke("run", exp, "-j", "1", "-q", "--tag", "owner=ana", "--tag", "ticket=EB-16")
    assert out.exit_code == 0, out.output
    assert invoke("run", exp, "-j", "1", "-q").exit_code == 0
    tagged, plain = RunStore(tmp_path / "runs").runs()
    assert tagged.info()["tags"] == {"owner": "ana", "ticket": "EB-16"} and plain.info()["tags"] == {}
    assert tagged.info()["config_hash"] == plain.info()["config_hash"]
    assert (tagged.path / "config.toml").read_text() == (plain.path / "config.toml").read_text()
    shown = invoke("runs", "show", tagged.id)
    assert "tags: owner=ana, ticket=EB-16" in shown.output.splitlines()
    listed = invoke("runs", "list", "--tag", "ticket=EB-16", "--width", "120").output.splitlines()
    assert len(listed) == 2 and listed[1].split()[0] == tagged.id and "owner=ana,ticket=EB-16" in listed[1]
    out = invoke("run", "--resume", tagged.id, "--tag", "a=b")
    assert out.exit_code == 2 and out.output.startswith("error: --tag is for a new run; tag ")
    out = invoke("run", exp, "--tag", "bad")
    assert out.exit_code == 2 and out.output == "error: --tag 'bad': write KEY=VALUE (e.g. --tag owner=ana)\n"


def _section(text: str, title: str) -> str:
    """The part of a several-run compare report from ``title`` to the next section or the end."""
    rest = text.split(f"\n{title}\n", 1)[1]
    return rest.split("\nC - A:\n", 1)[0] if title == "B - A:" else rest


def test_compare_of_three_runs_against_the_first(invoke, three):
    a, b, c = three
    out = invoke("compare", a.id, b.id, c.id, "--metrics", "all")
    assert out.exit_code == 0, out.output
    text = out.output
    assert text.startswith(f"Runs: A = {a.id}, B = {b.id}, C = {c.id}; each later run is compared with A.\n")
    assert "Note: B vs A: compared 4 metric row(s) of method(s) m1, m2 on target(s) y; skipped: nothing." in text
    assert ("Note: C vs A: compared 2 metric row(s) of method(s) m1 on target(s) y; skipped: method(s) m2 only in A; "
            "method(s) m3 only in C; target(s) z only in C.") in text
    # each later run's section is the two-run report of that pair (C labelled C)
    ab = invoke("compare", a.id, b.id, "--metrics", "all").output
    ac = invoke("compare", a.id, c.id, "--metrics", "all").output
    assert _section(text, "B - A:") == ab
    c_part = _section(text, "C - A:")
    assert c_part == ac.replace("B mean", "C mean").replace("B - A", "C - A").replace(", B = ", ", C = ") \
        .replace("in B,", "in C,").replace("Only in B (", "Only in C (")
    assert "better in C, 1 -> 0.5" in c_part and "(n 4 vs 4)" in c_part  # counts are integers
    # the side-by-side table: one column group per run, numbers of the pairwise comparisons
    side = text.split("Side by side (mean [interval] of each run; X - A: difference of the means):\n", 1)[1]
    rows = side.split("\n\nB - A:")[0].splitlines()
    assert rows[0] == "target y, mode static, window 0, split test"
    assert rows[1].split("  ")[0:2] == ["method", "metric"] and "C mean [interval]" in rows[1] and "C - A" in rows[1]
    cells = {tuple(r.split()[:2]): re.split(r"\s{2,}", r)[2:] for r in rows[3:]}
    assert set(cells) == {("m1", "mae"), ("m1", "rmse"), ("m2", "mae"), ("m2", "rmse")}
    pairwise = [compare_runs(a, x).table.set_index(["method", "metric"]) for x in (b, c)]
    for key, got in cells.items():
        ref = pairwise[0].loc[key]
        want = [f"{num(ref.mean_a)} [{num(ref.ci_low_a)}, {num(ref.ci_high_a)}]"]
        for t in pairwise:
            want += ([f"{num(t.loc[key].mean_b)} [{num(t.loc[key].ci_low_b)}, {num(t.loc[key].ci_high_b)}]",
                      num(t.loc[key].difference, 3)] if key in t.index else ["-", "-"])
        assert got == want, key
    assert cells[("m1", "mae")][2] == "0.55" and cells[("m1", "mae")][4] == "-0.5"  # 1.55 - 1, 0.5 - 1
    assert cells[("m2", "rmse")][3:] == ["-", "-"]  # c has no m2

def test_compare_csv_of_three_runs_is_the_pairwise_csvs(invoke, three):
    a, b, c = three
    many = pd.read_csv(io.StringIO(invoke("compare", a.id, b.id, c.id, "--format", "csv", "--metrics", "all").output))
    pairs = [pd.read_csv(io.StringIO(invoke("compare", a.id, x.id, "--format", "csv", "--metrics", "all").output))
             for x in (b, c)]
    assert list(many.columns[:2]) == ["run_a", "run_b"]
    assert list(many["run_b"]) == [b.id] * len(pairs[0]) + [c.id] * len(pairs[1]) and set(many["run_a"]) == {a.id}
    pd.testing.assert_frame_equal(many.drop(columns=["run_a", "run_b"]), pd.concat(pairs, ignore_index=True))
    assert many.loc[many["run_b"] == c.id, "paired"].eq(False).all() and many.loc[many["run_b"] == b.id, "paired"].all()
