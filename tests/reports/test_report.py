"""``enginebench report``: an HTML page with the run's tables and PNG figures drawn from re-fitted predictions."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.figure import Figure as MplFigure
from matplotlib.image import imread

from enginebench.cli.main import cli
from enginebench.reports.static import write_report
from enginebench.reports.static_figures import time_trend_plot
from enginebench.results import tables
from helpers import make_toy
from enginebench.results.store import RunStore
from enginebench.results.units import run_units

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _toy_run(root: Path, **changes):
    from enginebench.datasets.io import write_dataset
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict

    data = write_dataset(make_toy(), root / "toy.parquet")
    raw = {"name": "toy-report", "dataset": str(data), "targets": ["y"], "repetitions": 2, "seed": 3,
           "train_size": 120, "selection": {"kind": "bootstrap", "resamples": 2},
           "methods": {"naive-mean": {}, "krls": {"gamma_grid": [-2, 0, 3], "lambda_grid": [-3, -1, 3]}}}
    raw.update(changes)
    result = run_experiment(from_dict(raw, origin="test"), RunStore(root / "runs"), workers=1)
    assert result.n_failed == 0
    return result.run


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    return _toy_run(tmp_path_factory.mktemp("static"))


def _referenced(index: Path) -> set[str]:
    return set(re.findall(r'<img src="([^"]+)"', index.read_text()))


def _check_pngs(out: Path, result) -> None:
    written = {p.name for p in out.glob("*.png")}
    assert written and written == {f.path.name for f in result.figures}
    assert _referenced(result.index) == written  # every PNG is on the page, and nothing else is
    for name in written:
        data = (out / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 1000
        img = imread(out / name)
        assert img.ndim == 3 and img[..., :3].std() > 0.01  # not a blank canvas


def test_report_page_holds_the_tables_and_every_png(static_run, tmp_path):
    out = tmp_path / "rep"
    result = write_report(static_run, out)
    assert result.index == out / "index.html" and result.notes == []
    _check_pngs(out, result)
    assert sorted(f.kind for f in result.figures) == ["scatter", "scatter", "trend"]
    page = result.index.read_text()
    raw = static_run.metrics()
    summary = tables.summarize(raw)
    units = run_units(static_run.info())  # the comparison table exactly as `table --format html` prints it
    assert tables.to_html(summary, units=units) in page
    assert (out / "table.csv").read_text() == tables.to_csv(summary, units=units)
    paired = tables.paired_tests(raw, "mae")
    assert len(paired) == 1 and f"<td>{paired.iloc[0]['method']}</td><td>{paired.iloc[0]['versus']}</td>" in page
    assert static_run.id in page and "Config" in page and "Environment" in page
    assert 'gamma_grid = [' in page  # config.toml shown as stored


@pytest.mark.parametrize("repetition", [0, 1])
def test_figures_draw_the_refitted_predictions_of_the_chosen_repetition(static_run, tmp_path, monkeypatch, repetition):
    drawn: dict[str, MplFigure] = {}
    save = MplFigure.savefig

    def spy(self, fname, *args, **kwargs):
        drawn[Path(fname).name] = self
        return save(self, fname, *args, **kwargs)

    monkeypatch.setattr(MplFigure, "savefig", spy)
    result = write_report(static_run, tmp_path / "rep", repetition=repetition)
    preds = {p.method: p for p in result.predictions}
    assert sorted(preds) == ["krls", "naive-mean"]
    metrics = static_run.metrics()
    for name, p in preds.items():
        # the re-fit reproduces the run's own job: same training rows, same selected hyperparameters
        stored = metrics[(metrics["method"] == name) & (metrics["repetition"] == repetition)
                         & (metrics["split"] == "test") & (metrics["metric"] == "mae")]["value"]
        assert len(stored) == 1
        assert np.mean(np.abs(p.truth - p.pred)) == pytest.approx(float(stored.iloc[0]), rel=1e-9)
        assert p.repetition == repetition and len(p.truth) == 120  # the toy's test segment
        offsets = drawn[f"y__w0__published__scatter__{name}.png"].axes[0].collections[0].get_offsets()
        np.testing.assert_array_equal(np.asarray(offsets), np.column_stack([p.truth, p.pred]))
    lines = drawn["y__w0__published__trend.png"].axes[0].lines
    assert [ln.get_label() for ln in lines] == ["measured", "naive-mean", "krls"]
    np.testing.assert_array_equal(lines[0].get_ydata(), preds["krls"].truth)
    np.testing.assert_array_equal(lines[2].get_ydata(), preds["krls"].pred)
    # naive-mean predicts its training subsample's mean: one value, and it differs between repetitions
    assert np.ptp(preds["naive-mean"].pred) == 0


def test_repetitions_refit_on_different_training_rows(static_run, tmp_path):
    a = write_report(static_run, tmp_path / "a", repetition=0).predictions
    b = write_report(static_run, tmp_path / "b", repetition=1).predictions
    mean = {r: next(p for p in preds if p.method == "naive-mean").pred[0] for r, preds in ((0, a), (1, b))}
    assert mean[0] != mean[1]


def test_time_trend_breaks_lines_between_segments_and_refuses_mismatched_rows(tmp_path, monkeypatch):
    from enginebench.errors import MethodError
    from enginebench.reports.refit import Predictions

    t = np.r_[np.arange(5.0), 100 + np.arange(5.0)]
    seg = np.r_[np.zeros(5, int), np.ones(5, int)]
    y = np.arange(10.0)
    a = Predictions("y", 0.0, "published", "m1", "test", 0, t, y, y + 1, seg)
    drawn = {}
    save = MplFigure.savefig

    def spy(self, fname, *args, **kwargs):
        drawn["fig"] = self
        return save(self, fname, *args, **kwargs)

    monkeypatch.setattr(MplFigure, "savefig", spy)
    path = time_trend_plot([a], tmp_path / "t.png", title="x")
    assert path.read_bytes().startswith(PNG_MAGIC)
    ydata = np.asarray(drawn["fig"].axes[0].lines[1].get_ydata(), dtype=float)
    assert ydata.size == 11 and np.isnan(ydata[5])  # one NaN between the two segments: no joining line
    b = Predictions("y", 0.0, "published", "m2", "test", 0, t + 1, y, y, seg)
    with pytest.raises(MethodError, match="do not share the same rows"):
        time_trend_plot([a, b], tmp_path / "u.png")


def test_simulation_run_report_draws_trajectories_with_moe_gate_bands(tmp_path):
    from enginebench import registry
    from enginebench.methods.nfir import NFIR

    registry.register(NFIR)
    run = _toy_run(tmp_path, mode="simulation", repetitions=1, train_size=0, selection={"kind": "none"},
                   methods={"nfir": {"horizons": [2.0], "strides": [1], "gamma_grid": [-1, -1, 1], "lambda_grid": [-2, -2, 1]},
                            "moe": {"cpu_threads": 1}})
    out = tmp_path / "rep"
    result = write_report(run, out, trajectories=1)
    _check_pngs(out, result)
    kinds = {f.path.name: f.kind for f in result.figures}
    assert kinds == {"y__w0__s3.png": "trajectory", "y__w0__scatter__moe.png": "scatter",
                     "y__w0__scatter__nfir.png": "scatter"}
    trajectory = next(f for f in result.figures if f.kind == "trajectory")
    # the bands come from the method's explain hook and the caption names that method
    assert "moe gate weights as bands" in trajectory.caption and trajectory.caption in result.index.read_text()
    img = imread(out / "y__w0__s3.png")
    assert img.shape[:2] == (700, 1000)


def test_learning_curve_run_gets_its_curve(tmp_path):
    from enginebench.datasets.io import write_dataset
    from enginebench.experiments.learning_curve import curve_table, run_learning_curve, summarize_curve
    from enginebench.experiments.spec import from_dict

    data = write_dataset(make_toy(), tmp_path / "toy.parquet")
    spec = from_dict({"name": "toy-lc", "dataset": str(data), "targets": ["y"], "repetitions": 2, "seed": 1,
                      "train_size": 0, "selection": {"kind": "none"},
                      "methods": {"naive-mean": {}, "krls": {"gamma_grid": [0, 0, 1], "lambda_grid": [-2, -2, 1]}}},
                     origin="test")
    run = run_learning_curve(spec, [0.00005, 0.001], RunStore(tmp_path / "runs"), workers=1).run
    out = tmp_path / "rep"
    result = write_report(run, out)
    _check_pngs(out, result)
    assert [f.path.name for f in result.figures] == ["learning_curve.png"]
    page = result.index.read_text()
    assert "<h2>Learning curve</h2>" in page
    import html

    assert html.escape(curve_table(summarize_curve(run.metrics()))) in page
    assert any("learning-curve run" in n for n in result.notes)


def test_report_command(static_run, tmp_path):
    runner = CliRunner()
    store = str(static_run.path.parent)
    out = tmp_path / "cli"
    res = runner.invoke(cli, ["report", static_run.id, "-o", str(out), "--store", store, "--no-figures",
                              "--no-interactive"])
    assert res.exit_code == 0, res.output
    assert res.output.strip() == f"wrote {out / 'index.html'} (0 figures)"
    assert not list(out.glob("*.png")) and "Comparison table" in (out / "index.html").read_text()
    res = runner.invoke(cli, ["report", "latest", "-o", str(out), "--store", store, "--methods", "sindy"])
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [f"error: run {static_run.id} did not run method(s) sindy; it ran naive-mean, krls"]
    res = runner.invoke(cli, ["report", "nope", "-o", str(out), "--store", store])
    assert res.exit_code == 2 and res.output.startswith("error: no run 'nope'")


def test_the_reports_long_table_has_the_unit_of_mae(static_run, tmp_path):
    """table.csv beside the page gives each metric's unit as ``table --format csv`` does (mae in the target's unit)."""
    import io

    import pandas as pd

    result = write_report(static_run, tmp_path / "rep", figures=False)
    table = pd.read_csv(io.StringIO(result.table.read_text()), keep_default_na=False)
    units = dict(zip(table["metric"], table["unit"]))
    assert units["mae"] == "degC" and units["rmse"] == "degC" and units["mape"] == "%"
    assert "mae [degC]" in result.index.read_text()
