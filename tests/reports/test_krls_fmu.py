"""krls as an FMU (methods/export/models.py ``krls_c``, reports/fmu_export.py): a static-mode run exported and
run back through fmpy against the run's predictions; a window-mode model that reads past outputs refused in one
line; the hybrids built on KRLS offer no C step of krls's."""

from __future__ import annotations

import importlib.util
import shutil

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import MethodError
from enginebench.registry import get

HAVE_GCC = shutil.which("gcc") is not None
HAVE_FMPY = importlib.util.find_spec("fmpy") is not None
needs_gcc = pytest.mark.skipif(not HAVE_GCC, reason="no C compiler (gcc) on this machine")
needs_fmu = pytest.mark.skipif(not (HAVE_GCC and HAVE_FMPY), reason="FMU export needs gcc and fmpy (extra fmu)")

DT = 0.5
KRLS_OPTIONS = {"gamma_grid": [-1, -1, 1], "lambda_grid": [-3, -3, 1]}


def engine_map(sizes=(300, 200), seed=0) -> Dataset:
    """A static map of two inputs (speed, load) to an exhaust temperature, with noise: records 'est' and 'val'."""
    rng = np.random.default_rng(seed)
    frames = []
    for name, n in zip(("est", "val"), sizes):
        speed = rng.uniform(800.0, 2400.0, n)
        load = np.clip(50.0 + np.cumsum(rng.normal(0.0, 4.0, n)), 0.0, 100.0)
        temp = 300.0 + 0.12 * speed + 3.0 * load + 40.0 * np.sin(speed / 300.0) * load / 100.0
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(n) * DT, "speed": speed, "load": load,
                                    "t_exh": temp + rng.normal(0.0, 1.0, n)}))
    schema = Schema((Column("speed", "input", "rpm"), Column("load", "input", "%"), Column("t_exh", "output", "degC")))
    return Dataset("engine-map", pd.concat(frames, ignore_index=True), schema, DT, {"provenance": "test"})


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench.results.store import RunStore

    tmp = tmp_path_factory.mktemp("krls-static")
    path = write_dataset(engine_map(), tmp / "map.parquet")
    spec = from_dict({"name": "krls-static", "dataset": str(path), "targets": ["t_exh"], "mode": "static",
                      "repetitions": 1, "train_size": 0,
                      "split": {"kind": "records", "train": ["est"], "test": ["val"]},
                      "selection": {"kind": "kfold", "folds": 2}, "store": {"models": True},
                      "methods": {"krls": KRLS_OPTIONS}}, origin="test")
    return run_experiment(spec, RunStore(tmp / "runs"), workers=1).run


def fitted_krls(mode: str = "static", window: float = 0.0, **options):
    """A krls model fitted on 'est' directly (no run), with the samples of 'val' to predict."""
    ds = engine_map()
    data = make_samples(ds, ["t_exh"], mode, window)
    train = data.take(np.arange(data.segment_sizes[0]))
    test = data.take(np.arange(data.segment_sizes[0], len(data))).without_targets()
    method = get("krls")(**options)
    return method, method.fit(train, {"gamma": 0.1, "lambda": 1e-3}, np.random.default_rng(0)), train, test


@needs_fmu
def test_a_static_mode_krls_run_exports_an_fmu_that_reproduces_its_predictions(static_run, tmp_path):
    from click.testing import CliRunner

    from enginebench.cli.main import cli
    from enginebench.methods.export.fmu import simulate_fmu
    from enginebench.reports.fmu_export import find_model
    from enginebench.results.model_store import load_model

    out = tmp_path / "krls.fmu"
    res = CliRunner().invoke(cli, ["export", str(static_run.path), "--method", "krls", "--fmu", str(out)])
    assert res.exit_code == 0, res.output
    assert "checked with fmpy over 200 test steps against the run's predictions" in res.output
    print(res.output)
    # independently of the command's own check: the FMU's outputs against the run's stored test predictions
    stored = load_model(find_model(static_run.path, static_run.id, "krls", None, None))
    (seg,) = stored.check_data
    assert stored.meta["data"]["mode"] == "static" and stored.fitted.feature_names == ("speed", "load")
    Y, _ = simulate_fmu(out, seg["U"], np.zeros((1, 1)), 1, DT)
    pred = seg["prediction"]
    assert np.ptp(pred) > 50  # not vacuous: the map spans tens of degrees
    assert np.abs(Y[seg["rows"]] - pred).max() / np.abs(pred).max() <= 1e-9
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(out)) == []


@needs_gcc
@pytest.mark.parametrize("options", [{"standardize": True}, {"standardize": False, "center_target": False},
                                     {"solver": "falkon", "centres": 40}], ids=["exact", "raw", "falkon"])
def test_the_c_step_is_krls_predict(options):
    from dataclasses import replace

    from enginebench.methods.export.harness import run_c

    method, fitted, _, test = fitted_krls(**options)
    assert fitted.solver == options.get("solver", "exact")
    model = method.c_model(fitted)
    assert model.inputs == ("speed", "load") and model.u_lags == 1 and model.y_lags == 0
    (seg,) = test.segments
    Y, _, _ = run_c(replace(model, targets=("t_exh",)), seg.U, np.zeros((1, 1)), 1)
    pred = method.predict(fitted, test)[0]
    assert np.abs(Y[seg.rows] - pred).max() / np.abs(pred).max() <= 1e-9


@needs_gcc
def test_a_window_model_on_input_lags_alone_reads_the_input_history():
    """Window features without the past outputs (a feature selection): the inputs at lags 0..2, from uh."""
    from dataclasses import replace

    from enginebench.methods.export.harness import run_c

    data = make_samples(engine_map(), ["t_exh"], "window", 2 * DT)
    keep = [j for j, n in enumerate(data.feature_names) if not n.startswith("t_exh")]
    data = data.select_features(keep)
    train = data.take(np.arange(data.segment_sizes[0]))
    test = data.take(np.arange(data.segment_sizes[0], len(data))).without_targets()
    method = get("krls")()
    fitted = method.fit(train, {"gamma": 0.05, "lambda": 1e-3}, np.random.default_rng(0))
    model = replace(method.c_model(fitted), targets=("t_exh",))
    assert model.u_lags == 3 and model.inputs == ("speed", "load")
    (seg,) = test.segments
    assert seg.rows[0] == 2  # the first rows, whose window is incomplete, are not predicted
    Y, _, _ = run_c(model, seg.U, np.zeros((1, 1)), 1)
    pred = method.predict(fitted, test)[0]
    assert np.abs(Y[seg.rows] - pred).max() / np.abs(pred).max() <= 1e-9


def test_a_window_model_reading_past_outputs_is_refused_in_one_line():
    method, fitted, _, _ = fitted_krls("window", 2 * DT)
    with pytest.raises(MethodError) as err:
        method.c_model(fitted)
    assert str(err.value) == ("method 'krls' cannot be exported: its feature 't_exh[t-1]' is not an input but a past "
                              "measured output (window mode), which an FMU does not receive after its init window; "
                              "export a static-mode run of krls")


def test_a_model_stored_without_feature_names_is_refused_in_one_line():
    from dataclasses import replace

    method, fitted, _, _ = fitted_krls()
    with pytest.raises(MethodError, match=r"^method 'krls' cannot be exported: this stored model does not name its "
                                          r"features .*run the experiment again with --keep-models$"):
        method.c_model(replace(fitted, feature_names=(), input_names=()))


def test_krls_says_export_fmu_and_its_subclasses_offer_no_krls_c_step():
    from enginebench.c_model import exportable
    from enginebench.cli.methods import export_line
    from enginebench.methods.krls import KRLS

    assert exportable(get("krls")) and export_line(get("krls")).startswith("export: FMU of a static-mode model")
    for name in ("mtl-krls", "krls-pm", "residual-krls", "hybrid"):  # their own C steps (tests/reports/test_hybrid_fmu.py)
        assert get(name).c_model is not KRLS.c_model and get(name).export_note != KRLS.export_note, name

    class Plain(KRLS):  # predicts otherwise, defines no C step: none
        name = "plain-krls-subclass"

    assert not exportable(Plain) and export_line(Plain).startswith("export: none")
    assert exportable(get("nfir")) and export_line(get("nfir")).startswith("export: FMU (FMI 2.0")
