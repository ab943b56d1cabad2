"""Spec mistakes that only the data reveal are one `error:` line before the first job (issue 32, item 6): an
option naming a column the data lack (a cascade's ``intermediate``), lags longer than the records can carry."""

from __future__ import annotations

import pytest
import tomli_w
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.datasets.io import write_dataset
from enginebench.method import TrainingShape
from enginebench.methods.freerun import carried_lags
from helpers import make_toy


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return write_dataset(make_toy(), tmp_path_factory.mktemp("toy") / "toy.parquet")


def _run(tmp_path, toy, methods: dict) -> tuple[int, str]:
    exp = tmp_path / "e.toml"
    exp.write_text(tomli_w.dumps({"name": "x", "dataset": str(toy), "targets": ["y"], "repetitions": 1, "seed": 1,
                                  "mode": "simulation", "train_size": 0, "selection": {"kind": "none"},
                                  "methods": methods}))
    out = CliRunner().invoke(cli, ["run", str(exp), "-q", "-j", "1", "--store", str(tmp_path / "store")])
    assert not (tmp_path / "store").exists() or not any((tmp_path / "store").iterdir()), "a run folder was made"
    return out.exit_code, out.output


def test_an_unknown_cascade_intermediate_is_refused_before_the_first_job(tmp_path, toy):
    assert _run(tmp_path, toy, {"cascade": {"intermediate": "WF"}}) == (2, (
        "error: method 'cascade': option intermediate names 'WF', which is not a column of the data (run-time "
        "inputs: u1, u2; internal columns: none); name one of them, or give WF the role 'internal' "
        "(roles = { WF = \"internal\" })\n"))


def test_a_cascade_through_the_target_is_refused_before_the_first_job(tmp_path, toy):
    assert _run(tmp_path, toy, {"moe-nfir": {"intermediate": ["u1", "y"]}}) == (2, (
        "error: method 'moe-nfir': option intermediate names 'y', which is also the target; cascade through a column "
        "other than the target\n"))


def test_lags_beyond_the_records_are_refused_before_the_first_job(tmp_path, toy):
    assert _run(tmp_path, toy, {"naive-mean": {}, "arx": {"na": [5000]}}) == (2, (
        "error: method 'arx': option na = [5000] asks for 5000 lags, but the 3 training records of at most 120 "
        "samples (360 in all) have 0 samples with 5000 earlier ones in their record, fewer than the 5001 "
        "coefficients such a model has at least; use na of at most 89, or longer records (or leave na out to derive "
        "the grid from the data)\n"))


def test_a_grid_reaching_past_the_records_is_refused_and_one_within_them_runs(tmp_path, toy):
    code, out = _run(tmp_path, toy, {"narx": {"na": [2, 4, 90], "nb": [2]}})
    assert code == 2 and out.startswith("error: method 'narx': option na = [2, 4, 90] asks for 90 lags, but the 3 "
                                        "training records of at most 120 samples (360 in all) have 90 samples")
    exp = tmp_path / "e.toml"
    # the lag only: the tmp path may hold "90" too (pytest-290)
    exp.write_text(exp.read_text().replace("    90,\n", "    89,\n").replace('"narx"', '"arx"'))
    ok = CliRunner().invoke(cli, ["run", str(exp), "-q", "-j", "1", "--store", str(tmp_path / "ok")])
    assert ok.exit_code == 0, ok.output


def test_carried_lags_is_the_last_lag_whose_rows_outnumber_it():
    shape = TrainingShape(records=(120, 120, 120), inputs=("u",), targets=("y",), dt=1.0, mode="simulation")
    top = carried_lags(shape)
    assert shape.rows_after(top) > top and shape.rows_after(top + 1) <= top + 1 and top == 89
    assert carried_lags(TrainingShape((1,), (), ("y",), 1.0, "simulation")) == 0
    assert carried_lags(TrainingShape((), (), ("y",), 1.0, "simulation")) == 0


def test_an_input_window_longer_than_the_records_is_refused_before_the_first_job(tmp_path, toy):
    assert _run(tmp_path, toy, {"nfir": {"horizons": [10.0, 500.0]}}) == (2, (
        "error: method 'nfir': option horizons = [10.0, 500.0] s includes 500 s = 500 samples at dt = 1 s, as long as "
        "or longer than the longest of the 3 training records of at most 120 samples (360 in all); use horizons "
        "below 120 s (or leave horizons out to derive them from the data)\n"))
