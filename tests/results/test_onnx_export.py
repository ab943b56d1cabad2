"""ONNX export of the torch simulation models (methods/export/onnx.py, reports/onnx_export.py, export --onnx)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from enginebench.datasets.io import write_dataset
from enginebench.errors import MethodError
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.results.model_store import load_model
from enginebench.results.store import RunStore

from .test_model_store import model_file, records

HAVE_ORT = all(importlib.util.find_spec(m) is not None for m in ("onnx", "onnxruntime", "onnxscript"))
needs_onnx = pytest.mark.skipif(not HAVE_ORT, reason="ONNX export needs onnx, onnxscript and onnxruntime (extra onnx)")
pytest.importorskip("torch", reason="the ONNX-exportable methods are torch models")

SMALL = {"steps": 30, "batch_size": 16, "horizon": 20, "hidden": 8, "validations": 3, "lags": 4}
METHODS = {"neural-ss": {**SMALL, "nx": 3}, "gru": {**SMALL, "nx": 5}, "arx": {"na": [2], "nb": [2]}}


@pytest.fixture(scope="module")
def torch_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("onnx")
    path = write_dataset(records(), tmp / "recs.parquet")
    spec = from_dict({"name": "keep-torch", "dataset": str(path), "targets": ["y"], "mode": "simulation",
                      "repetitions": 1, "train_size": 0, "init_samples": 10,
                      "split": {"kind": "records", "train": ["est"], "test": ["val"]},
                      "selection": {"kind": "none"}, "store": {"models": True}, "methods": METHODS},
                     origin="test")
    return run_experiment(spec, RunStore(tmp / "runs"), workers=1).run


@needs_onnx
@pytest.mark.parametrize("method", ["neural-ss", "gru"])
def test_onnx_graphs_reproduce_the_runs_predictions(torch_run, tmp_path, method):
    from enginebench.methods.export.onnx import OnnxRunner
    from enginebench.reports.onnx_export import export_onnx

    result = export_onnx(model_file(torch_run, method), tmp_path / f"{method}.onnx", timing=True, run_id=torch_run.id)
    assert result.ok and result.tolerance == 1e-5
    assert result.max_rel <= 1e-5 and result.steps == 400 - 10
    assert result.path.is_file() and result.encoder == tmp_path / f"{method}.encoder.onnx"
    assert result.timing["onnxruntime_step"]["steps"] == 400 - 10
    # independently of the export's own check: the graphs, run by hand, against the stored model's simulate
    stored = load_model(model_file(torch_run, method))
    seg = stored.check_data[0]
    runner = OnnxRunner(result.path)
    assert runner.facts["method"] == method and runner.facts["targets"] == ["y"] and runner.facts["graph"] == "step"
    traj, _ = runner.simulate(seg["U"], seg["y_init"])
    mine = stored.simulate(seg["U"], seg["y_init"])
    assert mine.shape == (390, 1)
    np.testing.assert_allclose(traj[10:], mine, rtol=0, atol=1e-5 * np.abs(mine).max())
    # and the graph is not trivially equal: a wrong state changes the outputs
    state = runner.encoder.run(None, {"past_u": np.zeros((1, runner.lags, 1), np.float32),
                                      "past_y": np.zeros((1, runner.lags, 1), np.float32)})[0]
    y1 = runner.step.run(None, {"u": np.zeros((1, 1), np.float32), "state": state})[0]
    y2 = runner.step.run(None, {"u": np.zeros((1, 1), np.float32), "state": state + 1.0})[0]
    assert not np.allclose(y1, y2)


@needs_onnx
def test_cli_exports_onnx_and_prints_the_difference(torch_run, tmp_path):
    from enginebench.cli.main import cli

    out = tmp_path / "ss.onnx"
    res = CliRunner().invoke(cli, ["export", str(torch_run.path), "--method",
                                   "neural-ss", "--onnx", str(out), "--json"])
    assert res.exit_code == 0, res.output
    got = json.loads(res.output[res.output.index("{"):])
    assert got["ok"] and got["max_relative_difference"] <= 1e-5 and Path(got["encoder"]).is_file()


def test_a_method_without_graphs_is_refused_in_one_line(torch_run, tmp_path):
    from enginebench.reports.onnx_export import export_onnx

    with pytest.raises(MethodError) as err:
        export_onnx(model_file(torch_run, "arx"), tmp_path / "arx.onnx")
    assert str(err.value) == ("method 'arx' cannot be exported to ONNX: it offers no torch graph (ONNX: the methods "
                              "whose `methods show` says 'ONNX')")
    assert not (tmp_path / "arx.onnx").exists()


def test_methods_show_states_each_export():
    from enginebench.cli.methods import export_line
    from enginebench.registry import get

    assert export_line(get("gru")).startswith("export: ONNX")
    assert export_line(get("neural-ss")).startswith("export: ONNX")
    assert export_line(get("arx")).startswith("export: FMU")
    assert export_line(get("sindy")).startswith("export: none")
