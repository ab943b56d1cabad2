"""The marine-diesel physical model's C step (datasets/marine_diesel/c_step.py) and ``pm`` as an FMU."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.marine_diesel.pm import DEFAULT_PARAMS, RACK, SPEED, T_INLET, T_OUTLET, simulate_runs
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import MethodError
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.registry import get
from enginebench.results.store import RunStore

from .test_model_store import HAVE_FMPY, HAVE_GCC, model_file, needs_gcc

DT = 3.0


def profile(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Engine speed (rpm) and fuel rack (%) wandering over the engine's range, with steps."""
    rng = np.random.default_rng(seed)
    speed = np.clip(60 + np.cumsum(rng.normal(0, 1.0, n)), 20, 130)
    rack = np.clip(40 + np.cumsum(rng.normal(0, 0.8, n)), 5, 100)
    rack[n // 2:] += 15.0  # a load step
    return speed, rack


@needs_gcc
@pytest.mark.parametrize("params", [DEFAULT_PARAMS, {**DEFAULT_PARAMS, "tau_fuel_s": 0.0, "k_hr": 0.5}],
                         ids=["default", "no-pump-lag"])
def test_c_step_reproduces_the_vectorised_model(params):
    from enginebench.datasets.marine_diesel.c_step import TOLERANCE, c_model
    from enginebench.methods.export.harness import run_c

    speed, rack = profile(3000, 1)
    ref = simulate_runs(params, speed, rack, DT)
    ref = np.column_stack([ref[T_OUTLET], ref[T_INLET]])
    Y, _, diverged = run_c(c_model(params, DT, (T_OUTLET, T_INLET)), np.column_stack([speed, rack]), ref[:1], 1)
    assert not diverged
    rel = np.abs(Y - ref).max(axis=0) / np.abs(ref).max(axis=0)
    assert rel.max() <= TOLERANCE, rel
    # not vacuous: the outputs move by tens of degrees, and another sample period gives other lags
    assert np.ptp(ref, axis=0).min() > 10
    Y3, _, _ = run_c(c_model(params, 2 * DT, (T_OUTLET, T_INLET)), np.column_stack([speed, rack]), ref[:1], 1)
    assert np.abs(Y3 - ref).max() > 1e-3


def test_c_step_refuses_a_target_it_does_not_model():
    from enginebench.datasets.marine_diesel.c_step import c_model

    with pytest.raises(MethodError, match=r"^marine-diesel-pm: its C step predicts .*, not t_manifold$"):
        c_model(DEFAULT_PARAMS, DT, ("t_manifold",))


def test_pm_offers_a_c_step_only_for_a_model_that_has_one():
    pm = get("pm")()
    assert pm.c_model({"model": "fmu:thermal", "params": {}, "targets": ["tat"], "dt": 1.0}) is None
    assert pm.c_model({"model": "marine-diesel-pm", "params": DEFAULT_PARAMS}) is None  # fitted before targets/dt
    model = pm.c_model({"model": "marine-diesel-pm", "params": DEFAULT_PARAMS, "targets": [T_INLET], "dt": DT})
    assert model.inputs == (SPEED, RACK) and model.targets == (T_INLET,) and model.n_state == 4


def marine_records() -> Dataset:
    frames = []
    for name, n, seed in (("est", 300, 2), ("val", 500, 3)):
        speed, rack = profile(n, seed)
        sim = simulate_runs(DEFAULT_PARAMS, speed, rack, DT)
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(n) * DT, SPEED: speed, RACK: rack,
                                    T_INLET: sim[T_INLET] + 5.0}))
    schema = Schema((Column(SPEED, "input", "rpm"), Column(RACK, "input", "%"), Column(T_INLET, "output", "degC")))
    return Dataset("marine-tiny", pd.concat(frames, ignore_index=True), schema, DT,
                   {"provenance": "test", "physical_model": "marine-diesel-pm", "pm_calibration": "simulator",
                    "seed": 0})


@pytest.mark.skipif(not (HAVE_GCC and HAVE_FMPY), reason="FMU export needs gcc and fmpy (extra fmu)")
def test_pm_fmu_reproduces_the_runs_predictions(tmp_path):
    from enginebench.reports.fmu_export import export_fmu

    path = write_dataset(marine_records(), tmp_path / "marine.parquet")
    spec = from_dict({"name": "pm-fmu", "dataset": str(path), "targets": [T_INLET], "mode": "simulation",
                      "repetitions": 1, "train_size": 0,
                      "split": {"kind": "records", "train": ["est"], "test": ["val"]},
                      "selection": {"kind": "none"}, "store": {"models": True}, "methods": {"pm": {}}}, origin="test")
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    result = export_fmu(model_file(run, "pm"), tmp_path / "pm.fmu", timing=True, run_id=run.id)
    assert result.ok and result.tolerance == 1e-8 and result.steps == 500
    assert result.max_rel <= 1e-8
    assert result.timing["c_step"]["steps"] == 500  # measured and reported, never asserted
