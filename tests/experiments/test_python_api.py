"""The Python API (issue 34, item 1): run / open_run / Run.table / Run.jobs / Run.predictions, its one-line
errors, and docs/python.md's walk-through executed block by block."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import enginebench
from enginebench.api import TABLE_COLUMNS, EngineBenchError, Run, StoreError, open_run, run
from enginebench.cli.main import cli
from enginebench.datasets.io import write_dataset
from enginebench.errors import DataError, MethodError, SpecError
from helpers import make_toy

ROOT = Path(__file__).resolve().parents[2]


def toy_experiment(path: Path) -> dict:
    return {"name": "toy-api", "dataset": str(path), "targets": ["y"], "repetitions": 3, "seed": 7,
            "train_size": 150, "selection": {"kind": "bootstrap", "resamples": 2},
            "methods": {"naive-mean": {}, "ridge": {}}}


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory) -> Run:
    folder = tmp_path_factory.mktemp("api")
    data = write_dataset(make_toy(), folder / "toy.parquet")
    return run(toy_experiment(data), store=folder / "store", workers=1)


def cli_out(store: Path, *args: str) -> str:
    result = CliRunner().invoke(cli, [*args, "--store", str(store)], prog_name="enginebench")
    assert result.exit_code == 0, result.output
    return result.stdout


def test_table_equals_what_table_format_csv_prints(toy_run):
    frame = toy_run.table()
    printed = cli_out(toy_run.store, "table", toy_run.id, "--format", "csv")
    assert frame.rename(columns={v: k for k, v in TABLE_COLUMNS.items()}).to_csv(index=False) == printed
    back = pd.read_csv(io.StringIO(printed), keep_default_na=False, na_values=[""]).rename(columns=TABLE_COLUMNS)
    assert list(back.columns) == list(frame.columns)
    assert {"method", "target", "Delta", "split", "metric", "mean", "low", "high", "n", "interval"} <= set(frame.columns)
    pd.testing.assert_frame_equal(back[["mean", "low", "high", "n"]], frame[["mean", "low", "high", "n"]])
    mae = frame[(frame["metric"] == "mae") & (frame["method"] == "ridge")]
    raw = toy_run.metrics()
    assert mae["mean"].item() == pytest.approx(raw[(raw.metric == "mae") & (raw.method == "ridge")
                                                   & (raw.split == "test")]["value"].mean())
    only = toy_run.table(metrics=["mae", "rmse"])
    assert set(only["metric"]) == {"mae", "rmse"} and len(only) == 2 * 2  # 2 methods x 2 metrics
    with pytest.raises(DataError, match=r"^metrics: unknown metric\(s\) nope; run .* has "):
        toy_run.table(metrics="nope")


def test_jobs_one_row_per_job_with_the_picks_of_table_picks_csv(toy_run):
    jobs = toy_run.jobs()
    assert len(jobs) == 2 * 3 and set(jobs["status"]) == {"ok"} and set(jobs["reason"]) == {""}
    printed = pd.read_csv(io.StringIO(cli_out(toy_run.store, "table", toy_run.id, "--picks", "--format", "csv")))
    pd.testing.assert_frame_equal(jobs[list(printed.columns)].reset_index(drop=True), printed, check_dtype=False)
    ridge = jobs[jobs["method"] == "ridge"]
    assert ridge["param:alpha"].gt(0).all() and ridge["how"].eq("selected").all()
    assert jobs["time:fit_s"].ge(0).all()
    np.testing.assert_allclose(jobs["time:total_s"], jobs.filter(like="time:").drop(columns="time:total_s").sum(axis=1))
    assert list(jobs["repetition"][jobs["method"] == "ridge"]) == [0, 1, 2]


def test_predictions_reproduce_the_jobs_metric(toy_run):
    pred = toy_run.predictions("ridge", repetition=1)
    assert {"target", "window", "split", "method", "segment", "time", "truth", "prediction"} <= set(pred.columns)
    raw = toy_run.metrics()
    mae = raw[(raw.method == "ridge") & (raw.repetition == 1) & (raw.split == "test") & (raw.metric == "mae")]
    assert np.mean(np.abs(pred["truth"] - pred["prediction"])) == pytest.approx(mae["value"].item(), rel=1e-9)
    with pytest.raises(MethodError, match=r"^run .* did not run method 'krls'; it ran naive-mean, ridge$"):
        toy_run.predictions("krls")
    with pytest.raises(DataError, match=r"has no target 'z'"):
        toy_run.predictions("ridge", "z")


@pytest.mark.parametrize("ref, message", [
    (7, "open_run takes a run id or a run folder (str or Path), not int 7"),
    (None, "open_run takes a run id or a run folder (str or Path), not NoneType None"),
    ("", "an empty run reference; give a run id, a unique id prefix, 'latest' or a run folder"),
    ("no-such-run", "no run 'no-such-run' in {store}; 'enginebench runs list' shows the runs"),
    ("{store}/gone", "no run folder {store}/gone: it does not exist; give a run's folder, or its id in the store "
                     "{store} ('enginebench runs list' shows them)"),
])
def test_a_bad_run_reference_is_one_enginebench_error(tmp_path, ref, message):
    store = tmp_path / "store"
    store.mkdir()
    ref = ref.format(store=store) if isinstance(ref, str) else ref
    with pytest.raises(StoreError) as err:
        open_run(ref, store)
    assert isinstance(err.value, EngineBenchError) and str(err.value) == message.format(store=store)
    assert "\n" not in str(err.value)


def test_run_accepts_a_string_folder_and_refuses_another_type(toy_run):
    assert Run(str(toy_run.path)).id == toy_run.id
    assert open_run(str(toy_run.path)).table().equals(toy_run.table())
    assert open_run(toy_run).path == toy_run.path
    with pytest.raises(StoreError, match=r"^a run is opened from its folder or id \(str or Path\), not int 3; "):
        Run(3)  # type: ignore[arg-type]


def test_run_overrides_and_bad_experiments_are_spec_errors(tmp_path):
    with pytest.raises(SpecError, match="unknown experiment 'no-such-experiment'"):
        run("no-such-experiment", store=tmp_path)
    with pytest.raises(SpecError, match=r"^an experiment is a built-in name, a .toml path, a dict or an ExperimentSpec, "
                                        r"not int 3$"):
        run(3, store=tmp_path)  # type: ignore[arg-type]
    with pytest.raises(SpecError, match=r"^run\(\) overrides \(repetitionz\): unknown key\(s\) repetitionz \(did you mean 'repetitions'\?\)"):
        run("marine-diesel-egt-quick", store=tmp_path, repetitionz=2)
    assert not any(tmp_path.iterdir())  # nothing was run


def test_run_from_a_toml_path_with_tags_and_a_progress_callback(tmp_path):
    data = write_dataset(make_toy(), tmp_path / "toy.parquet")
    toml = tmp_path / "exp.toml"
    toml.write_text('name = "toy-toml"\ndataset = "toy.parquet"\ntargets = ["y"]\nrepetitions = 2\ntrain_size = 100\n'
                    '[selection]\nkind = "none"\n[methods.naive-mean]\n[methods.ridge]\n', encoding="utf-8")
    seen = []
    result = run(toml, store=tmp_path / "s", workers=1, tags={"who": "test"}, methods=["ridge"],
                 progress=lambda done, total, job: seen.append((done, total)))
    assert data.is_file() and result.info()["tags"] == {"who": "test"}
    assert result.config()["methods"] == ["ridge"] and seen[-1] == (2, 2)
    assert enginebench.open_run(result.id, tmp_path / "s").path == result.path


def python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(encoding="utf-8"), re.S)


def test_docs_python_md_walk_through_runs(tmp_path, monkeypatch):
    """Every python block of docs/python.md, in order, in one namespace (a notebook's kernel)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    blocks = python_blocks(ROOT / "docs" / "python.md")
    assert len(blocks) >= 4
    namespace: dict = {}
    for k, block in enumerate(blocks):
        exec(compile(block, f"docs/python.md block {k + 1}", "exec"), namespace)  # noqa: S102
    assert isinstance(namespace["result"], Run)


SCRIPT = """
from enginebench.api import run
exp = {{"name": "toy-api", "dataset": {data!r}, "targets": ["y"], "repetitions": 2, "seed": 7, "train_size": 150,
        "selection": {{"kind": "bootstrap", "resamples": 2}}, "methods": {{"naive-mean": {{}}, "ridge": {{}}}}}}
{call}
"""


@pytest.mark.parametrize("guarded", [False, True])
def test_a_script_calling_run_with_workers_needs_the_main_guard_and_says_so(tmp_path, guarded):
    """Worker processes import the script: unguarded, each would start a run of its own (leaving unfinished runs
    in the store); the run is refused there in one line, the parent says what to do, and one run is stored."""
    import subprocess
    import sys

    data = write_dataset(make_toy(), tmp_path / "toy.parquet")
    call = f"r = run(exp, store={str(tmp_path / 'store')!r}, workers=2)\nprint('stored', r.id)"
    if guarded:
        call = "if __name__ == '__main__':\n    " + call.replace("\n", "\n    ")
    script = tmp_path / "study.py"
    script.write_text(SCRIPT.format(data=str(data), call=call))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    runs = list((tmp_path / "store").iterdir())
    assert len(runs) == 1, runs
    if guarded:
        assert done.returncode == 0, done.stderr
        assert done.stdout.startswith("stored ")
        return
    assert done.returncode != 0
    assert ("EngineBenchError: enginebench.api.run was called while a worker process imported your script: put the "
            'call under `if __name__ == "__main__":`') in done.stderr
    assert "WorkerDied: a worker process died (" in done.stderr
    assert ("(fewer workers, `-j`, need less). From a Python script, call enginebench.api.run under "
            "`if __name__ == \"__main__\":`") in done.stderr


RANDOM_PLUGIN = '''
import numpy as np
from enginebench.method import Method

class Jitter(Method):
    """The training mean plus a random offset drawn at fit: each fit's model is a fresh draw."""
    name = "jitter"
    family = "baseline"
    def search_space(self, train):
        return {"scale": np.array([0.5, 1.0, 2.0])}
    def fit(self, train, params, rng):
        return np.mean(train.y, axis=0) + params["scale"] * rng.standard_normal(train.y.shape[1])
    def predict(self, fitted, data):
        return [np.tile(fitted, (len(s), 1)) for s in data.segments]
'''


def test_predictions_of_a_random_method_are_the_jobs_own_model(tmp_path):
    """The final fit draws from a generator of its own (experiments/jobs.py final_fit_rng), not from what the
    selection's draws left of the job's, so Run.predictions, the reports and the figures re-fit the very model
    the job scored, a random one included."""
    plugin = tmp_path / "jitter.py"
    plugin.write_text(RANDOM_PLUGIN)
    data = write_dataset(make_toy(), tmp_path / "toy.parquet")
    spec = {**toy_experiment(data), "methods": {"jitter": {}}}
    ran = run(spec, store=tmp_path / "store", workers=1, plugins=[plugin])
    raw = ran.metrics()
    maes = []
    for rep in range(3):
        pred = ran.predictions("jitter", repetition=rep)
        mae = raw[(raw.repetition == rep) & (raw.split == "test") & (raw.metric == "mae")]["value"].item()
        assert np.mean(np.abs(pred["truth"] - pred["prediction"])) == pytest.approx(mae, rel=1e-12)
        maes.append(mae)
    assert len(set(maes)) == 3  # the draws differ per repetition: the test would see a fresh draw


OFFSET_PLUGIN = '''
import numpy as np
from enginebench.method import Method

class Offsetter(Method):
    """The training mean plus an option's offset; its default is a class attribute a test changes."""
    name = "offsetter"
    family = "baseline"
    OFFSET = 1.0
    @classmethod
    def default_options(cls):
        return {"offset": cls.OFFSET}
    def fit(self, train, params, rng):
        return np.mean(train.y, axis=0) + float(self.options["offset"])
    def predict(self, fitted, data):
        return [np.tile(fitted, (len(s), 1)) for s in data.segments]
'''


def test_a_refit_uses_the_options_the_run_recorded_after_a_default_changed(tmp_path, monkeypatch):
    """run.json records every method's options, defaults included (experiments/recorded_options.py): a default
    changed since the run (a new version) does not change the model Run.predictions re-fits; a recorded option
    the method no longer has is one MethodError."""
    from enginebench import registry

    plugin = tmp_path / "offset.py"
    plugin.write_text(OFFSET_PLUGIN)
    data = write_dataset(make_toy(), tmp_path / "toy.parquet")
    ran = run({**toy_experiment(data), "methods": {"offsetter": {}, "ridge": {}}}, store=tmp_path / "store",
              workers=1, plugins=[plugin])
    assert ran.info()["method_options"]["offsetter"] == {"offset": 1.0}
    assert ran.info()["method_options"]["ridge"] == {"alpha_grid": [-6, 4, 21]}
    raw = ran.metrics()
    mae = raw[(raw.method == "offsetter") & (raw.repetition == 0) & (raw.split == "test") & (raw.metric == "mae")]
    monkeypatch.setattr(registry.get("offsetter"), "OFFSET", 5.0)  # the default of a later version
    pred = ran.predictions("offsetter", repetition=0)
    assert np.mean(np.abs(pred["truth"] - pred["prediction"])) == pytest.approx(mae["value"].item(), rel=1e-12)
    ran.update_info(method_options={**ran.info()["method_options"], "ridge": {"alpha_grid": [-6, 4, 21], "gone": 1}})
    with pytest.raises(MethodError, match=r"^run .*: ridge's options as the run recorded them no longer fit this "
                                          r"version of the method \(.*gone.*\); its jobs cannot be re-fitted or "
                                          r"resumed here$"):
        ran.predictions("ridge")
