"""The chosen model in view: `runs show` picks, `table --picks/--folds`, and `enginebench.api.open_run`/`picks_frame`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.api import StoreError, folds_frame, open_run, picks_frame
from enginebench.cli.main import cli
from enginebench.experiments.jobs import Job, selection_frame
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.selection import SelectionTable
from enginebench.results.job_files import SELECTION_META
from enginebench.results.picks import value_text
from enginebench.results.run_folder import Run
from enginebench.results.store import RunStore
from helpers import make_toy, toy_spec

ARX_SCORES = np.array([[0.5, 0.7], [0.2, 0.3], [0.25, 0.35], [0.9, 1.1]])
"""arx's selection scores (4 grid points x 2 resamples) in repetition 2: point 1 (gamma 0.01) wins; repetitions 0
and 1 swap points 1 and 2, so gamma 0.1 wins there (the value picked most is not the first in text order)."""


def _rows(method: str, rep: int, status: str = "ok") -> pd.DataFrame:
    return pd.DataFrame([{"dataset": "d", "target": "y", "mode": "static", "window": 0.0, "method": method,
                          "family": "test", "repetition": rep, "split": split, "metric": metric, "value": value,
                          "status": status} for split, metric, value in
                         (("test", "mae", 1.0 + rep), ("test", "rmae", 2.0), ("-", "time_fit_s", 0.1))])


def _meta(method: str, rep: int, params: dict | None, search: dict, status: str = "ok") -> dict:
    meta = {"job": f"y__w0__published__{method}__r{rep:03d}", "method": method, "target": "y", "window": 0.0,
            "split": "published", "repetition": rep, "status": status, "search": search}
    if params is not None:
        meta["params"] = params
    return meta


@pytest.fixture
def crafted(tmp_path) -> Run:
    """A run written through the store: arx picked gamma 0.1 twice and 0.01 once (stored tables); ridge a fixed
    alpha; naive-mean nothing; krls selected in an old run without tables; nfir failed before choosing."""
    store = RunStore(tmp_path / "runs")
    run = store.create("picks", {"name": "picks", "dataset": "d", "mode": "static", "interval": "t", "targets": ["y"],
                                 "methods": ["arx", "krls", "naive-mean", "nfir", "ridge"],
                                 "selection": {"kind": "kfold", "criterion": "mae"}},
                       "abcdef123456", {"python": "test"}, 8, plugins=[])
    grid = [{"na": 8, "nb": 8, "gamma": g, "lambda": 1e-10} for g in (0.001, 0.01, 0.1, 1.0)]
    for rep in range(3):
        scores = ARX_SCORES[[0, 2, 1, 3]] if rep < 2 else ARX_SCORES
        meta = _meta("arx", rep, grid[2 if rep < 2 else 1], {"grid_size": 4, "best_score": 0.25, "resamples": 2})
        table = SelectionTable(grid, scores, "mae", 2 if rep < 2 else 1).frame()
        meta[SELECTION_META] = selection_frame(table, Job("y", 0.0, "published", "arx", rep))
        run.write_job(meta["job"], _rows("arx", rep), meta)
    for rep in range(2):
        meta = _meta("ridge", rep, {"alpha": 1.0}, {"grid_size": 1})
        run.write_job(meta["job"], _rows("ridge", rep), meta)
    for meta in (_meta("naive-mean", 0, {}, {"grid_size": 1}),
                 _meta("krls", 0, {"gamma": 0.5, "lambda": 0.001}, {"grid_size": 9, "best_score": 0.2, "resamples": 5})):
        run.write_job(meta["job"], _rows(meta["method"], 0), meta)
    failed = {**_meta("nfir", 0, None, {}, status="failed"), "reason": "MethodError: boom"}
    run.write_job(failed["job"], _rows("nfir", 0, "failed"), failed)
    run.update_info(status="finished", finished_jobs=8, failed_jobs=1)
    return run


def invoke(run: Run, *args: str):
    return CliRunner().invoke(cli, [*args, "--store", str(run.store)], prog_name="enginebench")


def block(output: str, head: str) -> list[list[str]]:
    """The whitespace-split rows of the block of ``output`` whose first line starts with ``head`` (header row first)."""
    lines = output.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(head))
    rows = []
    for line in lines[start + 1:]:
        if not line.strip():
            break
        if set(line.strip()) != {"-"}:  # the rule under the header (results.term.grid)
            rows.append(line.split())
    return rows


def test_runs_show_lists_each_method_s_picks_with_counts(crafted):
    out = invoke(crafted, "runs", "show", crafted.id)
    assert out.exit_code == 0, out.output
    lines = out.output.splitlines()
    at = lines.index("selected hyperparameters (`enginebench table RUN --picks` lists every job):")
    assert lines[at + 1:] == [
        "  arx y: na=8; nb=8; gamma=0.1 (2/3), 0.01 (1/3); lambda=1e-10 (3 jobs)",
        "  krls y: gamma=0.5 lambda=0.001 (1 job)",
        "  naive-mean y: nothing to select (1 job)",
        "  nfir y: every job failed before choosing (1 job)",
        "  ridge y: alpha=1 [fixed: nothing scored] (all 2 jobs)",
    ]


def test_table_picks_prints_one_row_per_job_with_its_values(crafted):
    out = invoke(crafted, "table", crafted.id, "--picks")
    assert out.exit_code == 0, out.output
    assert block(out.output, "arx (3 jobs; selected):") == [
        ["target", "window", "split", "repetition", "na", "nb", "gamma", "lambda", "score", "grid"],
        ["y", "0", "published", "0", "8", "8", "0.1", "1e-10", "0.25", "4"],
        ["y", "0", "published", "1", "8", "8", "0.1", "1e-10", "0.25", "4"],
        ["y", "0", "published", "2", "8", "8", "0.01", "1e-10", "0.25", "4"],
    ]
    assert block(out.output, "ridge (2 jobs; fixed: nothing scored):")[1:] == [
        ["y", "0", "published", str(r), "1", "1"] for r in range(2)]
    assert "naive-mean: nothing to select (1 job)" in out.output.splitlines()
    assert block(out.output, "nfir (1 job; failed before choosing):")[0][-1] == "status"
    csv = invoke(crafted, "table", crafted.id, "--picks", "--format", "csv")
    frame = pd.read_csv(pd.io.common.StringIO(csv.output))
    arx = frame[frame["method"] == "arx"]
    assert arx["param:gamma"].tolist() == [0.1, 0.1, 0.01] and arx["param:na"].tolist() == [8, 8, 8]
    assert frame["how"].tolist() == ["selected"] * 4 + ["none", "failed", "fixed", "fixed"]


def test_table_folds_ranks_each_job_s_points_and_says_which_jobs_have_no_table(crafted):
    out = invoke(crafted, "table", crafted.id, "--folds", "--top", "2")
    assert out.exit_code == 0, out.output
    rows = block(out.output, "arx y window 0 published repetition 2 (mae on 2 folds; * = selected):")
    assert rows[0] == ["rank", "point", "na", "nb", "gamma", "lambda", "mean", "sd", "r0", "r1"]
    assert rows[1] == ["*1", "1", "8", "8", "0.01", "1e-10", "0.25", "0.0707107", "0.2", "0.3"]
    assert rows[2] == ["2", "2", "8", "8", "0.1", "1e-10", "0.3", "0.0707107", "0.25", "0.35"] and len(rows) == 3
    assert out.output.splitlines()[-4:] == [
        "no selection table: krls (1 job): selected in a run made before selection tables were stored, which keeps "
        "no per-fold scores; run the experiment again to get them",
        "no selection table: naive-mean (1 job): nothing to select",
        "no selection table: nfir (1 job): failed before choosing",
        "no selection table: ridge (2 jobs): nothing scored (a one-point grid or selection kind 'none')",
    ]
    both = invoke(crafted, "table", crafted.id, "--picks", "--folds")
    assert both.output.startswith("arx (3 jobs; selected):\n") and "repetition 0 (mae on 2 folds" in both.output
    frame = folds_frame(crafted, top=1)
    assert frame["rank"].tolist() == [1, 1, 1] and frame["chosen"].all()
    assert frame["resample:0"].tolist() == [0.2, 0.2, 0.2] and frame["param:gamma"].tolist() == [0.1, 0.1, 0.01]


@pytest.mark.parametrize("args, message", [
    (["--picks", "--format", "md"], "error: --picks and --folds print term or csv tables; see 'enginebench table --help'"),
    (["--picks", "--folds", "--format", "csv"], "error: --format csv prints one table: give --picks or --folds (the "
                                                "folds' rows hold the picked values too); see 'enginebench table --help'"),
])
def test_table_picks_refuses_other_formats_in_one_line(crafted, args, message):
    out = invoke(crafted, "table", crafted.id, *args)
    assert out.exit_code == 2 and out.output == message + "\n"


def test_open_run_by_id_prefix_path_and_its_one_line_errors(crafted, tmp_path, monkeypatch):
    store = crafted.store
    for ref in (crafted.id, crafted.id[:15], "latest", str(crafted.path), crafted.path):
        assert open_run(ref, store).path == crafted.path, ref
    monkeypatch.setenv("ENGINEBENCH_STORE", str(store))
    assert open_run(crafted.id).path == crafted.path  # the default store
    with pytest.raises(StoreError) as err:
        open_run("nope", store)
    assert str(err.value) == f"no run 'nope' in {store}; 'enginebench runs list' shows the runs"
    (tmp_path / "plain").mkdir()
    with pytest.raises(StoreError) as err:
        open_run(str(tmp_path / "plain"), store)
    assert str(err.value) == (f"{tmp_path / 'plain'} is not a run folder (it has no run.json); give a run's folder, "
                              f"or its id in the store {store} ('enginebench runs list' shows them)")
    with pytest.raises(StoreError) as err:
        open_run(tmp_path / "gone", store)
    assert str(err.value).startswith(f"no run folder {tmp_path / 'gone'}: it does not exist; give a run's folder")
    with pytest.raises(StoreError, match="^open_run takes a run id or a run folder .str or Path., not int 7$"):
        open_run(7, store)  # type: ignore[arg-type]  (an EngineBenchError: one line, issue 34)
    assert Run(str(crafted.path)).id == crafted.id and Run(str(crafted.path)).info()["name"] == "picks"
    with pytest.raises(TypeError, match="^Run takes a run folder .str or Path., not NoneType None; "):
        Run(None)  # type: ignore[arg-type]
    out = invoke(crafted, "runs", "show", str(tmp_path / "plain"))
    assert out.exit_code == 2 and out.output.startswith(f"error: {tmp_path / 'plain'} is not a run folder")
    out = invoke(crafted, "table", "nope", "--picks")
    assert out.exit_code == 2 and out.output == f"error: no run 'nope' in {store}; 'enginebench runs list' shows the runs\n"


@pytest.fixture(scope="module")
def real_run(tmp_path_factory) -> Run:
    """A tiny real experiment: naive mean and a 3 x 3 KRLS grid, 2 repetitions, bootstrap selection."""
    from enginebench.datasets.io import write_dataset

    root = tmp_path_factory.mktemp("picks")
    data = write_dataset(make_toy(), root / "toy.parquet")
    return run_experiment(toy_spec(data, repetitions=2), RunStore(root / "runs"), workers=1).run


def test_a_real_run_s_picks_are_its_selection_table_s_chosen_points(real_run):
    table = real_run.selection_table()
    chosen = table[table["chosen"]].drop_duplicates("repetition").set_index("repetition")
    picks = picks_frame(real_run)
    krls = picks[picks["method"] == "krls"].set_index("repetition")
    assert len(krls) == 2 and (krls["how"] == "selected").all() and krls["folds_stored"].all()
    for name in ("gamma", "lambda"):
        assert krls[f"param:{name}"].tolist() == chosen[f"param:{name}"].tolist()
    shown = invoke(real_run, "runs", "show", real_run.id).output.splitlines()
    values = {n: [value_text(v) for v in chosen[f"param:{n}"]] for n in ("gamma", "lambda")}
    if len(set(values["gamma"])) == 1 and len(set(values["lambda"])) == 1:
        assert f"  krls y: gamma={values['gamma'][0]} lambda={values['lambda'][0]} (all 2 jobs)" in shown
    else:
        assert any(line.startswith("  krls y: gamma=") and line.endswith("(2 jobs)") for line in shown)
    assert "  naive-mean y: nothing to select (2 jobs)" in shown
    rows = block(invoke(real_run, "table", real_run.id, "--picks").output, "krls (2 jobs; selected):")
    assert [r[4:6] for r in rows[1:]] == [[values["gamma"][i], values["lambda"][i]] for i in range(2)]
    folds = folds_frame(real_run)
    best = folds[folds["chosen"]].set_index("repetition")
    assert best["mean"].tolist() == pytest.approx(krls["score"].tolist(), rel=1e-12)
    for rep in range(2):
        scores = table[table["chosen"] & (table["repetition"] == rep)].sort_values("resample")["score"]
        assert best.loc[rep, ["resample:0", "resample:1"]].tolist() == scores.tolist()
    assert Path(open_run(real_run.id, real_run.store).path) == real_run.path
