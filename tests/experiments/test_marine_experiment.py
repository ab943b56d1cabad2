"""The marine-diesel experiment: built-in specs, a tiny end-to-end run, the PM's calibration, learning curves."""

from __future__ import annotations

import pickle

import click
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.datasets.dataset import TIME
from enginebench.datasets.io import write_dataset
from enginebench.datasets.marine_diesel import generate
from enginebench.datasets.marine_diesel.calibration import seed_fat_params, simulator_fat_params
from enginebench.datasets.marine_diesel.physical_model import MarineDieselPM
from enginebench.datasets.marine_diesel.pm import simulate_frame
from enginebench.datasets.splits import make_splits
from enginebench.errors import DataError, SpecError
from enginebench.experiments.engine import physical_model_for
from enginebench.experiments.learning_curve import (
    MONTH_S, first_months, parse_months, prepare_curve, run_learning_curve, summarize_curve,
)
from enginebench.experiments.runner import prepare, run_experiment
from enginebench.experiments.spec import load_spec
from enginebench.results.store import RunStore

TARGETS = ("t_exhaust_turbine_inlet", "t_exhaust_turbine_outlet")
TINY = {"naive-mean": {}, "pm": {},
        "krls": {"gamma_grid": [-3, -1, 3], "lambda_grid": [-3, -1, 3]},
        "mtl-krls": {"gamma_grid": [-3, -1, 3], "lambda_grid": [-3, -1, 3], "theta_grid": [-2, 0, 2]}}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    ds = generate("small", seed=0)
    return ds, write_dataset(ds, tmp_path_factory.mktemp("marine") / "marine-diesel-small.parquet")


def tiny_spec(path, **changes):
    spec = load_spec("marine-diesel-egt-quick")
    base = dict(dataset=str(path), dataset_variant="", repetitions=1, train_size=150,
                selection={"kind": "bootstrap", "resamples": 1, "folds": 5, "criterion": "mae"},
                methods=list(TINY), method_options=TINY)
    base.update(changes)
    return spec.with_overrides(**base)


# -- the built-in specs -------------------------------------------------------------------------

def test_builtin_specs_load_with_the_seed_protocol():
    full, quick = load_spec("marine-diesel-egt"), load_spec("marine-diesel-egt-quick")
    for spec in (full, quick):
        assert spec.dataset == "marine-diesel" and spec.targets == TARGETS
        assert spec.mode == "window" and {0.0, 30.0} <= set(spec.windows)
        assert spec.methods == ("naive-mean", "ridge", "pm", "krls", "mtl-krls")
        assert spec.selection.kind == "bootstrap" and spec.split == {"kind": "published"}
        assert spec.roles == {}
    assert full.dataset_variant == "full" and full.repetitions == 30
    assert full.windows == (0.0, 9.0, 18.0, 30.0)   # the egt-hybrid paper's 0/10/20/30 s at dt = 3 s
    assert full.method_options["krls"] == {"gamma_grid": [-4, 4, 41], "lambda_grid": [-4, 4, 41]}
    assert full.method_options["mtl-krls"]["theta_grid"] == [-4, 4, 41]
    assert quick.dataset_variant == "small" and quick.repetitions < full.repetitions
    assert quick.method_options["mtl-krls"]["gamma_grid"][2] < 41


def test_windows_are_multiples_of_the_sample_period_and_inputs_do_not_leak(small):
    ds, path = small
    assert ds.dt == 3.0
    ctx = prepare(tiny_spec(path, windows=[0, 30]))
    for (target, window, _), problem in ctx.problems.items():
        names = problem.train.feature_names
        assert len(names) == len(set(names))
        exhaust = {n.split("[")[0] for n in names if n.startswith("t_exhaust")}
        # only the target's own past may appear, and only in window mode, strictly before t
        assert exhaust == (set() if window == 0 else {target})
        assert not any(n.startswith(target) and n.endswith("[t]") for n in names)
        if window:
            assert f"{target}[t-10]" in names and f"{target}[t-11]" not in names
    internal = set(ds.schema.internals)
    assert {f"t_exhaust_{w}_turbine_{b}" for w in ("before", "after") for b in "ab"} <= internal


# -- the physical model's calibration -------------------------------------------------------------

def test_dataset_asks_for_the_simulator_fat_calibration(small):
    ds, _ = small
    assert ds.meta["pm_calibration"] == "simulator"
    pm = physical_model_for(ds)
    assert isinstance(pm, MarineDieselPM) and pm.calibration == "simulator" and pm.seed == 0
    other = MarineDieselPM.for_dataset({"pm_calibration": "seed", "seed": 3})
    assert other.calibration == "seed" and other.seed == 3
    with pytest.raises(DataError, match="pm_calibration='fat' is not one of simulator, seed"):
        MarineDieselPM.for_dataset({"pm_calibration": "fat"})
    with pytest.raises(DataError, match="calibration must be one of"):
        MarineDieselPM(calibration="data")


def test_pm_is_pickled_with_its_calibration_resolved():
    pm = MarineDieselPM()
    clone = pickle.loads(pickle.dumps(pm))
    assert clone._params == simulator_fat_params(0) == pm.calibrate([])
    assert clone.calibrate([]) != seed_fat_params()
    given = pickle.loads(pickle.dumps(MarineDieselPM({"x": 1.0})))
    assert given.params == {"x": 1.0} and given.given


# -- a tiny end-to-end run ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny_run(small, tmp_path_factory):
    _, path = small
    spec = tiny_spec(path, windows=[0, 9])
    return run_experiment(spec, RunStore(tmp_path_factory.mktemp("runs")), workers=1)


def test_tiny_run_has_rows_for_every_method_at_both_windows(tiny_run):
    assert tiny_run.n_failed == 0
    m = tiny_run.run.metrics()
    mae = m[(m["metric"] == "mae") & (m["split"] == "test")]
    got = set(zip(mae["target"], mae["window"], mae["method"]))
    assert got == {(t, w, meth) for t in TARGETS for w in (0.0, 9.0) for meth in TINY}
    assert np.isfinite(mae["value"]).all()
    hybrid = tiny_run.run.job_meta("t_exhaust_turbine_inlet__w9__published__mtl-krls__r000")
    assert set(hybrid["params"]) == {"gamma", "lambda", "theta"} and hybrid["search"]["grid_size"] == 3 * 3 * 2


def test_pm_rows_are_the_simulator_calibrated_model_on_the_test_voyages(small, tiny_run):
    ds, _ = small
    test = make_splits(ds)[0].test
    pred = simulate_frame(simulator_fat_params(0), test.frame, ds.dt)
    seed_pred = simulate_frame(seed_fat_params(), test.frame, ds.dt)
    m = tiny_run.run.metrics()
    for target in TARGETS:
        y = test.frame[target].to_numpy()
        expected = float(np.mean(np.abs(pred[target] - y)))
        row = m[(m["metric"] == "mae") & (m["split"] == "test") & (m["method"] == "pm")
                & (m["window"] == 0) & (m["target"] == target)]
        assert row["value"].iloc[0] == pytest.approx(expected, rel=1e-10)
        assert expected < float(np.mean(np.abs(seed_pred[target] - y)))


# -- learning curves ------------------------------------------------------------------------------

def test_parse_months():
    assert parse_months("2, 0.5,1") == [0.5, 1.0, 2.0]
    for bad in ("", "0,1", "-1", "a,b", "1,1", "nan"):
        with pytest.raises(SpecError, match="--months"):
            parse_months(bad)


def test_first_months_keeps_the_earliest_rows_by_time(small):
    ds, _ = small
    train = make_splits(ds)[0].train
    t0 = train.frame[TIME].min()
    sizes = []
    for months in (0.01, 0.03, 0.06, 1.0):
        cut = first_months(train, months, min_rows=11)
        t = cut.frame[TIME].to_numpy()
        assert t.max() < t0 + months * MONTH_S
        assert cut.frame.groupby("segment").size().min() >= 11
        # every kept row is a row of the training part, unchanged
        merged = cut.frame.merge(train.frame, on=["segment", TIME], suffixes=("", "_orig"))
        assert len(merged) == len(cut) and np.array_equal(merged[TARGETS[0]], merged[TARGETS[0] + "_orig"])
        sizes.append(len(cut))
    assert sizes == sorted(sizes) and sizes[0] < sizes[-1] == len(train)


def test_amounts_grow_proportionally_or_stay_fixed(small):
    _, path = small
    spec = tiny_spec(path, windows=[0], targets=["t_exhaust_turbine_inlet"], train_size=600, methods=["krls"],
                     method_options={"krls": TINY["krls"]})
    prop = prepare_curve(spec, [0.01, 0.05, 1.0]).amounts
    assert [a.train_size for a in prop] == sorted(a.train_size for a in prop)
    assert prop[-1].train_size == 600 and prop[0].train_size < 600
    assert prop[-1].whole and not prop[0].whole
    total = prop[-1].available_rows["published"]
    assert prop[0].train_size == max(50, round(600 * prop[0].available_rows["published"] / total))
    fixed = prepare_curve(spec, [0.01, 0.05, 1.0], rows="fixed").amounts
    assert [a.train_size for a in fixed] == [600, 600, 600]
    with pytest.raises(SpecError, match="rows must be one of"):
        prepare_curve(spec, [1.0], rows="all")


def test_learning_curve_run_stores_one_run_with_rows_growing_with_months(small, tmp_path):
    _, path = small
    spec = tiny_spec(path, windows=[0], targets=["t_exhaust_turbine_inlet"], train_size=400, repetitions=2,
                     methods=["naive-mean", "krls"], method_options={"krls": TINY["krls"]})
    result = run_learning_curve(spec, [0.01, 0.1], RunStore(tmp_path / "runs"), workers=1)
    assert result.n_failed == 0 and result.n_jobs == 2 * 2 * 2
    m = result.run.metrics()
    scored = m[m["split"] != "-"]
    assert set(scored["split"]) == {"test@0.01mo", "test@0.1mo"}
    n_train = scored.groupby("train_months")["n_train"].agg(["min", "max"])
    assert n_train.loc[0.01, "max"] < n_train.loc[0.1, "min"]
    assert n_train.loc[0.01, "max"] == result.amounts[0].train_size
    summary = summarize_curve(m)
    assert len(summary) == 2 * 2 and set(summary["n_repeats"]) == {2}
    pd.testing.assert_frame_equal(summary, result.run.read_table("learning_curve.parquet"))
    krls = summary[summary["method"] == "krls"].set_index("train_months")
    vals = scored[(scored["method"] == "krls") & (scored["metric"] == "mae") & (scored["train_months"] == 0.1)]["value"]
    assert krls.loc[0.1, "mean"] == pytest.approx(vals.mean())
    assert result.run.info()["kind"] == "learning-curve"


def test_learning_curve_command_prints_the_table(small, tmp_path):
    from enginebench.cli.learning_curve import learning_curve
    from enginebench.cli.main import Group

    _, path = small
    exp = tmp_path / "tiny.toml"
    exp.write_text(f"""
name = "tiny-marine"
dataset = "{path}"
targets = ["t_exhaust_turbine_outlet"]
mode = "window"
windows = [0]
repetitions = 1
train_size = 200
[selection]
kind = "bootstrap"
resamples = 1
[methods.krls]
gamma_grid = [-3, -1, 2]
lambda_grid = [-3, -1, 2]
""")

    @click.group(cls=Group)
    def app() -> None:
        pass

    app.add_command(learning_curve)
    result = CliRunner().invoke(app, ["learning-curve", str(exp), "--months", "0.02,0.2", "--methods", "krls",
                                      "-q", "--store", str(tmp_path / "runs"), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("t_exhaust_turbine_outlet")]
    assert [line.split()[2] for line in lines] == ["0.02", "0.2"]
    assert "(n=1)" in lines[0]
    assert "plot: " in result.output or "plot skipped: matplotlib is not installed" in result.output
    bad = CliRunner().invoke(app, ["learning-curve", str(exp), "--months", "0", "--store", str(tmp_path / "runs")])
    assert bad.exit_code == 2 and "positive number of months" in bad.output
