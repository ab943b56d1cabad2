"""The KRLS hybrids as FMUs (methods/export/models.py ``pm_kernel_c``: the physical model's own C step, then the
kernel sum on the features, plus the PM for residual learning): static-mode runs of every hybrid on a small
gas-turbine-like system exported and run back through fmpy against the run's predictions (1e-9 relative); the
gas-turbine TAT model's C step against its numpy form; a window model reading past outputs and a physical
model without a C step refused in one line."""

from __future__ import annotations

import importlib.util
import shutil
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import MethodError
from enginebench.physical import get_physical_model
from enginebench.registry import get

HAVE_GCC = shutil.which("gcc") is not None
HAVE_FMPY = importlib.util.find_spec("fmpy") is not None
needs_gcc = pytest.mark.skipif(not HAVE_GCC, reason="no C compiler (gcc) on this machine")
needs_fmu = pytest.mark.skipif(not (HAVE_GCC and HAVE_FMPY), reason="FMU export needs gcc and fmpy (extra fmu)")

DT = 600.0
GRID = {"gamma_grid": [-1, -1, 1], "lambda_grid": [-2, -2, 1]}
MTL_GRID = {**GRID, "theta_grid": [0, 0, 1]}
HYBRIDS = {"krls-pm": GRID, "residual-krls": GRID, "residual-krls-pm": GRID, "mtl-krls": MTL_GRID,
           "mtl-krls-task": MTL_GRID, "hybrid": {**MTL_GRID, "strategies": ["shared"]}}


def turbine(sizes=(250, 150), seed=0) -> Dataset:
    """TIT, CDP, AP, GTEP -> TAT by a polytropic expansion plus what it misses (a load-dependent term), with noise;
    the gas-turbine TAT model declared as the physical model. Records 'est' and 'val'."""
    rng = np.random.default_rng(seed)
    frames = []
    for name, n in zip(("est", "val"), sizes):
        load = np.clip(0.6 + np.cumsum(rng.normal(0.0, 0.03, n)), 0.2, 1.0)
        tit = 1000.0 + 90.0 * load + rng.normal(0.0, 2.0, n)
        cdp = 9.0 + 6.0 * load + rng.normal(0.0, 0.1, n)
        ap = 1013.0 + rng.normal(0.0, 5.0, n)
        gtep = 20.0 + 12.0 * load + rng.normal(0.0, 0.5, n)
        tat = (tit + 273.15) * ((ap + gtep) / (0.97 * cdp * 1000.0)) ** 0.27 - 273.15 + 3.0 + 8.0 * np.sin(6 * load)
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(n) * DT, "TIT": tit, "CDP": cdp, "AP": ap,
                                    "GTEP": gtep, "TAT": tat + rng.normal(0.0, 0.3, n)}))
    schema = Schema((Column("AP", "input", "mbar"), Column("CDP", "input", "bar"), Column("GTEP", "input", "mbar"),
                     Column("TIT", "input", "degC"), Column("TAT", "output", "degC")))
    return Dataset("turbine-tiny", pd.concat(frames, ignore_index=True), schema, DT,
                   {"provenance": "test", "physical_model": "gas-turbine-tat"})


@pytest.fixture(scope="module")
def hybrid_run(tmp_path_factory):
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench.results.store import RunStore

    tmp = tmp_path_factory.mktemp("hybrid-static")
    path = write_dataset(turbine(), tmp / "turbine.parquet")
    spec = from_dict({"name": "hybrid-static", "dataset": str(path), "targets": ["TAT"], "mode": "static",
                      "repetitions": 1, "train_size": 0,
                      "split": {"kind": "records", "train": ["est"], "test": ["val"]},
                      "selection": {"kind": "none"}, "store": {"models": True}, "methods": HYBRIDS}, origin="test")
    return run_experiment(spec, RunStore(tmp / "runs"), workers=1).run


@needs_fmu
@pytest.mark.parametrize("method", list(HYBRIDS))
def test_each_hybrid_exports_an_fmu_that_reproduces_its_predictions(hybrid_run, tmp_path, method):
    from click.testing import CliRunner

    from enginebench.cli.main import cli
    from enginebench.methods.export.fmu import simulate_fmu
    from enginebench.reports.fmu_export import find_model
    from enginebench.results.model_store import load_model

    out = tmp_path / f"{method}.fmu"
    res = CliRunner().invoke(cli, ["export", str(hybrid_run.path), "--method", method, "--fmu", str(out)])
    assert res.exit_code == 0, res.output
    assert "checked with fmpy over 150 test steps against the run's predictions" in res.output
    print(res.output)
    # independently of the command's own check: the FMU's outputs against the run's stored test predictions
    stored = load_model(find_model(hybrid_run.path, hybrid_run.id, method, None, None))
    (seg,) = stored.check_data
    from fmpy import read_model_description

    names = stored.meta["data"]["input_names"]
    ins = [v.name for v in read_model_description(str(out)).modelVariables if v.causality == "input"
           and not v.name.endswith("_measured")]
    assert sorted(ins) == ["AP", "CDP", "GTEP", "TIT"]
    Y, _ = simulate_fmu(out, seg["U"][:, [names.index(c) for c in ins]], np.zeros((1, 1)), 1, DT)
    pred = seg["prediction"]
    assert np.ptp(pred) > 10  # not vacuous: TAT moves by tens of degrees
    assert np.abs(Y[seg["rows"]] - pred).max() / np.abs(pred).max() <= 1e-9
    # not the PM alone: the kernel part moves the prediction by more than the tolerance
    pm = get_physical_model("gas-turbine-tat")
    model = stored.fitted if method == "mtl-krls" else stored.fitted.model
    p = pm.simulate(stored.fitted.pm_params, {c: seg["U"][:, j] for j, c in enumerate(("AP", "CDP", "GTEP", "TIT"))},
                    DT)["TAT"][seg["rows"]]
    assert np.abs(pred[:, 0] - p).max() > 0.1, model


def fitted(method: str, mode: str = "static", window: float = 0.0):
    """``method`` fitted on 'est' directly (no run), with the samples of 'val' to predict."""
    data = make_samples(turbine(), ["TAT"], mode, window, physical_model=get_physical_model("gas-turbine-tat"))
    train = data.take(np.arange(data.segment_sizes[0]))
    test = data.take(np.arange(data.segment_sizes[0], len(data))).without_targets()
    m = get(method)(**HYBRIDS[method])
    params = {"gamma": 0.1, "lambda": 0.01}
    if "theta_grid" in HYBRIDS[method]:
        params["theta"] = 1.0
    if method == "hybrid":
        params["strategy"] = "shared"
    return m, m.fit(train, params, np.random.default_rng(0)), test


@needs_gcc
@pytest.mark.parametrize("method", ["residual-krls-pm", "mtl-krls-task"])
def test_a_window_model_of_a_zero_window_reads_the_inputs_alone(method):
    from enginebench.methods.export.harness import run_c

    m, fit, test = fitted(method, "window", 0.0)
    model = m.c_model(fit)
    assert model.inputs == ("AP", "CDP", "GTEP", "TIT") and model.u_lags == 1 and model.y_lags == 0
    (seg,) = test.segments
    Y, _, _ = run_c(model, seg.U, np.zeros((1, 1)), 1)
    pred = m.predict(fit, test)[0]
    assert np.abs(Y[seg.rows] - pred).max() / np.abs(pred).max() <= 1e-9


@pytest.mark.parametrize("method", ["krls-pm", "mtl-krls"])
def test_a_window_model_reading_past_outputs_is_refused_in_one_line(method):
    m, fit, _ = fitted(method, "window", 2 * DT)
    with pytest.raises(MethodError) as err:
        m.c_model(fit)
    assert str(err.value) == (f"method {method!r} cannot be exported: its feature 'TAT[t-1]' is not an input but a "
                              "past measured output (window mode), which an FMU does not receive after its init "
                              "window; export a static-mode run (or a window of 0 s)")


@pytest.mark.parametrize("method", ["residual-krls", "mtl-krls", "hybrid"])
def test_a_physical_model_without_a_c_step_is_refused_in_one_line(method):
    m, fit, _ = fitted(method)
    fit = replace(fit, pm_name="fmu:thermal")
    if method != "mtl-krls":
        fit = replace(fit, model=replace(fit.model, pm_name="fmu:thermal") if method == "hybrid" else fit.model)
    with pytest.raises(MethodError) as err:
        m.c_model(fit)
    assert str(err.value) == (f"method {method!r} cannot be exported: its physical model 'fmu:thermal' has no C step "
                              "(the marine-diesel-pm and gas-turbine-tat models have one); export a method without "
                              "it (krls)")


def test_a_model_stored_before_the_c_step_is_refused_in_one_line():
    m, fit, _ = fitted("residual-krls")
    with pytest.raises(MethodError, match=r"^method 'residual-krls' cannot be exported: this stored model does not "
                                          r"name its physical model .*--keep-models$"):
        m.c_model(replace(fit, pm_name="", target_names=(), dt=0.0))


@needs_gcc
def test_the_gas_turbine_c_step_is_the_model():
    from enginebench.methods.export.harness import run_c

    ds = turbine()
    frame = ds.frame
    pm = get_physical_model("gas-turbine-tat")
    params = {"k": 0.2712345678901, "b": 2.5}
    ref = pm.simulate(params, {c: frame[c].to_numpy() for c in pm.inputs}, DT)["TAT"]
    Y, _, _ = run_c(pm.c_model(params, DT, ("TAT",)), frame[list(pm.inputs)].to_numpy(), np.zeros((1, 1)), 1)
    assert np.abs(Y[:, 0] - ref).max() / np.abs(ref).max() <= 1e-15
    with pytest.raises(MethodError, match=r"^gas-turbine-tat: its C step predicts TAT, not EGT$"):
        pm.c_model(params, DT, ("EGT",))


def test_the_hybrids_say_export_fmu():
    from enginebench.c_model import exportable
    from enginebench.cli.methods import export_line

    for name in HYBRIDS:
        assert exportable(get(name)) and export_line(get(name)).startswith("export: FMU of a static-mode model"), name


@needs_gcc
@pytest.mark.parametrize("strategy", ["feature", "residual", "residual-feature", "task"])
def test_hybrid_exports_the_strategy_it_selected(strategy):
    from enginebench.methods.export.harness import run_c

    data = make_samples(turbine(), ["TAT"], "static", 0.0, physical_model=get_physical_model("gas-turbine-tat"))
    train = data.take(np.arange(data.segment_sizes[0]))
    test = data.take(np.arange(data.segment_sizes[0], len(data))).without_targets()
    m = get("hybrid")(**MTL_GRID, strategies=[strategy])
    params = {"strategy": strategy, "gamma": 0.1, "lambda": 0.01, **({"theta": 1.0} if strategy == "task" else {})}
    fit = m.fit(train, params, np.random.default_rng(0))
    assert fit.strategy == strategy
    (seg,) = test.segments
    Y, _, _ = run_c(m.c_model(fit), seg.U, np.zeros((1, 1)), 1)
    pred = m.predict(fit, test)[0]
    assert np.abs(Y[seg.rows] - pred).max() / np.abs(pred).max() <= 1e-9


@pytest.mark.skipif(not (HAVE_GCC and HAVE_FMPY), reason="FMU export needs gcc and fmpy (extra fmu)")
def test_marine_hybrids_export_with_the_marine_models_states(tmp_path):
    """The marine-diesel PM's C step has states (lags) and stops its charge-pressure solve otherwise than pm.py:
    the hybrids' FMUs agree with the run to the PM's own tolerance (1e-8 relative), states started with the
    segment as the run's simulation of it."""
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench.reports.fmu_export import export_fmu
    from enginebench.results.store import RunStore

    from ..results.test_model_store import model_file
    from ..results.test_pm_fmu import T_INLET, marine_records

    path = write_dataset(marine_records(), tmp_path / "marine.parquet")
    methods = {"residual-krls": GRID, "mtl-krls": MTL_GRID}
    spec = from_dict({"name": "marine-hybrid-fmu", "dataset": str(path), "targets": [T_INLET], "mode": "static",
                      "repetitions": 1, "train_size": 0,
                      "split": {"kind": "records", "train": ["est"], "test": ["val"]},
                      "selection": {"kind": "none"}, "store": {"models": True}, "methods": methods}, origin="test")
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    for method in methods:
        result = export_fmu(model_file(run, method), tmp_path / f"{method}.fmu", run_id=run.id)
        assert result.ok and result.tolerance == 1e-8 and result.steps == 500, (method, result)
        print(method, result.max_rel)


@needs_gcc
@pytest.mark.parametrize("method, options", [("mtl-krls", {"pm_feature": False}),
                                             ("krls-pm", {"standardize": False, "center_target": False}),
                                             ("residual-krls", {"solver": "falkon", "centres": 40})],
                         ids=["mtl-no-pm-feature", "raw", "falkon"])
def test_the_c_step_follows_the_options(method, options):
    from enginebench.methods.export.harness import run_c

    data = make_samples(turbine(), ["TAT"], "static", 0.0, physical_model=get_physical_model("gas-turbine-tat"))
    train = data.take(np.arange(data.segment_sizes[0]))
    test = data.take(np.arange(data.segment_sizes[0], len(data))).without_targets()
    m = get(method)(**HYBRIDS[method], **options)
    params = {"gamma": 0.1, "lambda": 0.01, **({"theta": 1.0} if method == "mtl-krls" else {})}
    fit = m.fit(train, params, np.random.default_rng(0))
    model = m.c_model(fit)
    assert any(n.startswith("pm:") for n in getattr(fit, "model", fit).feature_names) == (method == "krls-pm")
    (seg,) = test.segments
    Y, _, _ = run_c(model, seg.U, np.zeros((1, 1)), 1)
    pred = m.predict(fit, test)[0]
    assert np.abs(Y[seg.rows] - pred).max() / np.abs(pred).max() <= 1e-9
