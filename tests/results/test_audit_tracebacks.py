"""Inputs that used to end in a traceback now give one `error:` line (or work): a CSV field over 128 KiB,
an infinite window, a --since age beyond the calendar."""

from __future__ import annotations

from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.results.store import RunStore
from helpers import stored_run


def records_parquet(tmp_path, *, records: int, rows: int, nan_at: int | None = None):
    """A Parquet dataset of ``records`` records s0, s1, ... of ``rows`` samples: input u, output y (random);
    ``nan_at``: a NaN in y at that row of s0."""
    import numpy as np
    import pandas as pd

    from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
    from enginebench.datasets.io import write_dataset
    from enginebench.datasets.schema import Column, Schema

    rng = np.random.default_rng(0)
    frame = pd.concat([pd.DataFrame({SEGMENT: f"s{k}", TIME: np.arange(float(rows)), "u": rng.normal(size=rows),
                                     "y": rng.normal(size=rows)}) for k in range(records)], ignore_index=True)
    if nan_at is not None:
        frame.loc[nan_at, "y"] = np.nan
    return write_dataset(Dataset("d", frame, Schema((Column("u", "input"), Column("y", "output"))), 1.0, {}),
                         tmp_path / "d.parquet")


def test_a_field_over_128_kib_is_read_and_reported_in_one_short_line(tmp_path):
    (tmp_path / "big.csv").write_text("u,y\n1," + "7" * 140_000 + "x\n2,3\n4,5\n")
    (tmp_path / "big.toml").write_text('name = "b"\ndt = 1.0\nfiles = ["big.csv"]\n[columns]\n'
                                       'u = { role = "input" }\ny = { role = "output" }\n')
    out = CliRunner().invoke(cli, ["datasets", "show", str(tmp_path / "big.toml")])
    assert out.exit_code == 2, out.output
    line = out.output.strip()
    assert line.startswith("error: ") and "\n" not in line and len(line) < 400
    assert "(140001 characters)" in line and "is not a number" in line


def test_a_header_field_over_128_kib_is_read(tmp_path):
    name = "u" + "x" * 140_000
    (tmp_path / "h.csv").write_text(f"{name},y\n1,2\n2,3\n")
    (tmp_path / "h.toml").write_text('name = "h"\ndt = 1.0\nfiles = ["h.csv"]\n[columns]\n'
                                     'y = { role = "output" }\n')
    out = CliRunner().invoke(cli, ["datasets", "show", str(tmp_path / "h.toml")])
    assert out.exit_code == 0, out.output


def test_an_infinite_window_is_refused(tmp_path):
    exp = tmp_path / "e.toml"
    exp.write_text('dataset = "d.parquet"\ntargets = ["y"]\nmode = "window"\nwindows = [inf]\nmethods = ["naive-mean"]\n')
    out = CliRunner().invoke(cli, ["run", str(exp), "-q"])
    assert out.exit_code == 2 and "'windows' must be finite numbers of seconds, got [inf]" in out.output


def test_a_since_age_beyond_the_calendar_lists_every_run(tmp_path):
    store = RunStore(tmp_path / "runs")
    run = stored_run(store, "one", {"naive-mean": [1.0]})
    out = CliRunner().invoke(cli, ["runs", "list", "--since", "99999999999999999999d", "--store", str(store.root)])
    assert out.exit_code == 0 and run.id[:20] in out.output


def test_an_infinite_grid_count_is_one_line():
    import pytest

    from enginebench.errors import MethodError
    from enginebench.methods.krls import KRLS

    with pytest.raises(MethodError, match=r"option gamma_grid=\[-4, 4, inf\] must be \(low exponent, high exponent, "
                                          r"count\)"):
        KRLS(gamma_grid=[-4, 4, float("inf")])


def test_an_empty_mlflow_uri_is_refused_and_creates_nothing(tmp_path, monkeypatch):
    import pytest

    pytest.importorskip("mlflow")
    store = RunStore(tmp_path / "runs")
    stored_run(store, "one", {"naive-mean": [1.0]})
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    out = CliRunner().invoke(cli, ["export", "latest", "--mlflow", "", "--store", str(store.root)])
    assert out.exit_code == 2 and "an empty tracking URI (an unset variable?)" in out.output
    assert list(work.iterdir()) == []


def test_a_garbled_run_json_field_makes_the_run_damaged_not_a_traceback(tmp_path):
    import json

    store = RunStore(tmp_path / "runs")
    run = stored_run(store, "one", {"naive-mean": [1.0]})
    for field, value in (("tags", "garbled"), ("resumes", 7), ("tags", {"a": 1})):
        info = json.loads((run.path / "run.json").read_text())
        (run.path / "run.json").write_text(json.dumps({**info, field: value}))
        for args in (["runs", "show", run.id], ["table", run.id], ["runs", "tag", run.id, "a=b"]):
            out = CliRunner().invoke(cli, [*args, "--store", str(store.root)])
            assert out.exit_code == 2 and out.output.startswith(f"error: run {run.id}") and \
                f"run.json field {field!r}" in out.output and len(out.output.strip().splitlines()) == 1, out.output
        listed = CliRunner().invoke(cli, ["runs", "list", "--store", str(store.root)])
        assert listed.exit_code == 0 and "damaged" in listed.output
        (run.path / "run.json").write_text(json.dumps(info))


def test_a_text_group_column_made_an_input_is_one_line(tmp_path):
    (tmp_path / "d.csv").write_text("t,u,g,y\n0,1,a,2\n1,2,a,3\n2,3,b,1\n3,1,b,2\n4,5,a,3\n5,1,b,1\n")
    (tmp_path / "d.toml").write_text('name = "grp"\ndt = 1.0\nfiles = ["d.csv"]\ntime = "t"\n[columns]\n'
                                     'u = { role = "input" }\ng = { role = "group" }\ny = { role = "output" }\n')
    exp = tmp_path / "e.toml"
    exp.write_text('dataset = "d.toml"\ntargets = ["y"]\nrepetitions = 1\ntrain_size = 0\nroles = { g = "input" }\n'
                   '[split]\nkind = "holdout"\n[selection]\nkind = "none"\n[methods.naive-mean]\n')
    out = CliRunner().invoke(cli, ["run", str(exp), "-q", "--store", str(tmp_path / "runs")])
    assert out.exit_code == 2
    assert out.output.strip() == ("error: dataset 'grp', column 'g': holds text ('a' at row 0), so it cannot have "
                                  "role 'input' (roles = { g = \"input\" }); only numeric columns can be inputs, "
                                  "outputs or internals")


def test_an_option_naming_a_missing_input_is_refused_before_the_first_job(tmp_path):
    path = records_parquet(tmp_path, records=2, rows=60)
    exp = tmp_path / "e.toml"
    exp.write_text(f'dataset = "{path}"\ntargets = ["y"]\nmode = "simulation"\nrepetitions = 1\ntrain_size = 0\n'
                   '[split]\nkind = "records"\ntrain = ["s0"]\ntest = ["s1"]\n[selection]\nkind = "none"\n'
                   '[methods.boost-fir]\ninputs = ["nope"]\n')
    out = CliRunner().invoke(cli, ["run", str(exp), "-q", "--store", str(tmp_path / "runs")])
    assert out.exit_code == 2 and out.output.strip() == (
        "error: method 'boost-fir': option inputs names 'nope': not a run-time input of the data; its inputs are u")
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_compare_of_two_simulation_runs_uses_the_simulation_metrics(tmp_path):
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict

    path = records_parquet(tmp_path, records=3, rows=80)
    store = RunStore(tmp_path / "runs")
    ids = []
    for seed in (0, 1):
        spec = from_dict({"name": "s", "dataset": str(path), "targets": ["y"], "mode": "simulation", "seed": seed,
                          "repetitions": 2, "train_size": 0, "init_samples": 2,
                          "split": {"kind": "records", "train": ["s0", "s1"], "test": ["s2"]},
                          "selection": {"kind": "none"}, "methods": ["naive-mean"]}, origin="test")
        ids.append(run_experiment(spec, store, workers=1).run.id)
    out = CliRunner().invoke(cli, ["compare", *ids, "--store", str(store.root)])
    assert out.exit_code == 0, out.output
    assert " rmse " in out.output and " nrmse " in out.output and "mape" not in out.output


def test_an_empty_column_name_a_huge_dt_and_an_infinite_tolerance_are_refused(tmp_path):
    import pytest

    from enginebench.datasets.importer import import_table
    from enginebench.errors import DataError, SpecError
    from enginebench.results.guard import parse_tolerance

    (tmp_path / "a.csv").write_text("u,y\n1,2\n2,3\n3,1\n")
    for body, message in (('dt = 1e308\n[columns]\nu = { role = "input" }\n', "dt must be a positive number of "
                           r"seconds, got 1e\+308 \(at most 1e7 s"),
                          ('dt = 1\n[columns]\n"" = { role = "input" }\n', "has a column with an empty name")):
        (tmp_path / "s.toml").write_text('name = "x"\nfiles = ["a.csv"]\n' + body + 'y = { role = "output" }\n')
        with pytest.raises(SpecError, match=message):
            import_table(tmp_path / "s.toml")
    with pytest.raises(DataError, match="beyond the double range"):
        parse_tolerance("1e999%")


def test_work_beyond_any_run_is_refused_before_the_data_are_read(tmp_path, monkeypatch):
    exp = tmp_path / "e.toml"
    exp.write_text('dataset = "nowhere.parquet"\ntargets = ["y"]\nmethods = ["naive-mean"]\n')
    out = CliRunner().invoke(cli, ["run", str(exp), "--repeats", str(10**12), "-q", "--store", str(tmp_path / "r")])
    assert out.exit_code == 2 and "plans at least 1,000,000,000,000 jobs" in out.output
    assert "set ENGINEBENCH_MAX_JOBS to raise it" in out.output
    exp.write_text('dataset = "nowhere.parquet"\ntargets = ["y"]\nmethods = ["naive-mean"]\n'
                   '[selection]\nkind = "bootstrap"\nresamples = 10000000\n')
    out = CliRunner().invoke(cli, ["run", str(exp), "-q", "--store", str(tmp_path / "r")])
    assert out.exit_code == 2 and "asks for 10,000,000 fits per job and grid point" in out.output
    monkeypatch.setenv("ENGINEBENCH_MAX_FITS", str(10**8))
    out = CliRunner().invoke(cli, ["run", str(exp), "-q", "--store", str(tmp_path / "r")])
    assert out.exit_code == 2 and "nowhere.parquet" in out.output  # past the limit: on to the data


def test_a_run_whose_every_job_failed_prints_each_reason(tmp_path):
    path = records_parquet(tmp_path, records=2, rows=50, nan_at=5)
    exp = tmp_path / "e.toml"
    exp.write_text(f'dataset = "{path}"\ntargets = ["y"]\nmode = "simulation"\nrepetitions = 1\ntrain_size = 0\n'
                   '[split]\nkind = "records"\ntrain = ["s0"]\ntest = ["s1"]\n[selection]\nkind = "none"\n'
                   '[methods.naive-mean]\n[methods.arx]\n')
    store = str(tmp_path / "runs")
    out = CliRunner().invoke(cli, ["run", str(exp), "-q", "-j", "1", "--store", store])
    assert out.exit_code == 1 and "none of the metrics" not in out.output
    assert "no table: every one of the 2 jobs failed" in out.output
    assert "training segment 's0' has nan/inf in target 'y' at row 5" in out.output
    table = CliRunner().invoke(cli, ["table", "latest", "--store", store])
    assert table.exit_code == 2 and "has nan/inf in target 'y'" in table.output
    assert "no job of run" in table.output and "none of the metrics" not in table.output


def test_a_target_constant_to_rounding_has_no_nrmse():
    import numpy as np

    from enginebench.results.metrics import compute_metrics

    up = np.nextafter(1.0, 2.0)
    values, notes = compute_metrics([np.array([1.0, up, 1.0, up])], [np.ones(4)], 1.0)
    assert np.isnan(values["nrmse"]) and np.isnan(values["fit"]) and np.isnan(values["r2"])
    assert "target constant to rounding" in notes["nrmse"]
    tiny = np.array([1e-10, 2e-10, 3e-10])  # a small signal is not constant: its spread is far above rounding
    values, _ = compute_metrics([tiny], [tiny * 1.1], 1e-10)
    assert np.isfinite(values["nrmse"])


def test_a_named_pipe_as_a_data_file_is_refused_at_once(tmp_path):
    import os

    import pytest

    from enginebench.datasets.importer import import_table
    from enginebench.errors import DataError

    os.mkfifo(tmp_path / "a.csv")
    (tmp_path / "s.toml").write_text('name = "x"\ndt = 1.0\nfiles = ["a.csv"]\n[columns]\nu = { role = "input" }\n'
                                     'y = { role = "output" }\n')
    with pytest.raises(DataError, match="not a regular file"):
        import_table(tmp_path / "s.toml")
    os.mkfifo(tmp_path / "d.parquet")
    exp = tmp_path / "e.toml"
    exp.write_text(f'dataset = "{tmp_path / "d.parquet"}"\ntargets = ["y"]\nmethods = ["naive-mean"]\n')
    out = CliRunner().invoke(cli, ["run", str(exp), "-q", "--store", str(tmp_path / "r")])
    assert out.exit_code == 2 and out.output.startswith("error: ")


def test_krls_fits_targets_of_any_scale_alike():
    from dataclasses import replace

    import numpy as np

    from enginebench.methods.krls import KRLS
    from enginebench.testing import tiny_samples

    train, test = tiny_samples("static")
    m, p = KRLS(), {"gamma": 0.1, "lambda": 1e-2}
    base = np.concatenate(m.predict(m.fit(train, p, np.random.default_rng(0)), test.without_targets()))
    for f in (2.0 ** -700, 2.0 ** 600):  # powers of two: the same numbers, exactly (1e-200 was 17 % off before)
        scaled = replace(train, segments=tuple(replace(s, y=s.y * f) for s in train.segments))
        out = np.concatenate(m.predict(m.fit(scaled, p, np.random.default_rng(0)), test.without_targets()))
        np.testing.assert_array_equal(out / f, base)
        grid = m.predict_grid(scaled, test.without_targets(), [p], np.random.default_rng(0))[0]
        np.testing.assert_allclose(grid / f, base, rtol=1e-12)


def test_an_experiment_name_with_a_quote_is_explained_for_mlflow(tmp_path):
    import pytest

    pytest.importorskip("mlflow")
    store = RunStore(tmp_path / "runs")
    stored_run(store, "o'brien", {"naive-mean": [1.0, 2.0]})
    out = CliRunner().invoke(cli, ["export", "latest", "--mlflow", str(tmp_path / "ml"), "--store", str(store.root)])
    assert out.exit_code == 2 and "a quote (') breaks; pass --experiment with a name without one" in out.output
    ok = CliRunner().invoke(cli, ["export", "latest", "--mlflow", str(tmp_path / "ml"), "--experiment", "obrien",
                                  "--store", str(store.root)])
    assert ok.exit_code == 0, ok.output
