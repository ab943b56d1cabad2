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


@needs_onnx
def test_a_failed_onnx_check_leaves_files_already_at_the_output_paths(torch_run, tmp_path, monkeypatch):
    """The graphs are built in a hidden folder beside the output and moved over it only once they agree with the
    run: when the check fails (here: a tolerance no difference can meet), the step and encoder files already at
    the output paths are byte for byte as they were, no staged graph is left, and the command fails in one line."""
    from enginebench.cli.main import cli
    from enginebench.reports import onnx_export

    out = tmp_path / "ss.onnx"
    enc = tmp_path / "ss.encoder.onnx"
    out.write_bytes(b"an earlier step graph")
    enc.write_bytes(b"an earlier encoder graph")
    monkeypatch.setattr(onnx_export, "TOLERANCE", {"float32": -1.0, "float64": -1.0})
    result = onnx_export.export_onnx(model_file(torch_run, "neural-ss"), out, run_id=torch_run.id)
    assert not result.ok and not result.written and result.steps == 400 - 10 and result.max_rel <= 1e-5
    assert (result.path, result.encoder) == (out, enc)
    assert out.read_bytes() == b"an earlier step graph" and enc.read_bytes() == b"an earlier encoder graph"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ss.encoder.onnx", "ss.onnx"]
    # and through the command, which used to remove both files
    res = CliRunner().invoke(cli, ["export", str(torch_run.path), "--method", "neural-ss", "--onnx", str(out)])
    assert res.exit_code == 2, res.output
    assert f"did not write {out} (the step) and {enc} (the initial state)" in res.output
    assert "above -1; they were not written" in res.output
    assert out.read_bytes() == b"an earlier step graph" and enc.read_bytes() == b"an earlier encoder graph"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ss.encoder.onnx", "ss.onnx"]


@needs_onnx
def test_a_passed_onnx_check_replaces_files_already_at_the_output_paths(torch_run, tmp_path):
    """Once the graphs agree they replace the files at the output paths (both of them) and the staging folder
    is gone; the graphs' metadata name their final files."""
    from enginebench.methods.export.onnx import OnnxRunner
    from enginebench.reports.onnx_export import export_onnx

    out = tmp_path / "gru.onnx"
    enc = tmp_path / "gru.encoder.onnx"
    out.write_bytes(b"old")
    enc.write_bytes(b"old")
    result = export_onnx(model_file(torch_run, "gru"), out, run_id=torch_run.id)
    assert result.ok and result.written and (result.path, result.encoder) == (out, enc)
    assert out.read_bytes() != b"old" and enc.read_bytes() != b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gru.encoder.onnx", "gru.onnx"]
    runner = OnnxRunner(out)
    assert runner.facts["step_graph"] == "gru.onnx" and runner.facts["encoder_graph"] == "gru.encoder.onnx"
