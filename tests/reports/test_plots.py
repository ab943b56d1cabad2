"""Figures: trajectory plots with gate bands and scatter plots render to PNGs of the stated size, not blank."""

from __future__ import annotations

import numpy as np
import pytest

from matplotlib.image import imread

from enginebench.errors import DataError, MethodError
from enginebench.reports.plots import scatter_plot, trajectory_plot


def _signals(n: int = 300):
    t = np.arange(n) / 12.0
    true = 40 + 10 * np.sin(t / 3)
    sims = {"moe": true + 0.5 * np.cos(t), "sindy": true * 1.02, "nfir": true - 1.0}
    logits = np.column_stack([np.sin(t / 5), np.cos(t / 7), 0 * t])
    gate = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
    return t, true, sims, gate


def _not_blank(path):
    img = imread(path)
    colours = np.unique(img[..., :3].reshape(-1, 3), axis=0)
    assert img[..., :3].std() > 0.05 and len(colours) > 50
    return img


def test_trajectory_plot_with_inputs_and_gate_bands(tmp_path):
    t, true, sims, gate = _signals()
    path = trajectory_plot(t, true, sims, gate, tmp_path / "sub" / "traj.png", inputs={"COL": np.sin(t), "NR": np.cos(t)},
                           scale=40.0, title="TRQ, test trajectory", ylabel="TRQ")
    assert path == tmp_path / "sub" / "traj.png" and path.is_file()
    img = _not_blank(path)
    assert img.shape[:2] == (700, 1000)  # 10 x 7 inches at 100 dpi
    # the lowest panel holds the stacked gate bands: the colours of the first three default cycle entries
    bottom = img[560:680, 150:900, :3].reshape(-1, 3)
    for hexcol in ("#1f77b4", "#ff7f0e", "#2ca02c"):
        rgb = np.array([int(hexcol[i:i + 2], 16) for i in (1, 3, 5)]) / 255
        blended = 0.85 * rgb + 0.15  # alpha 0.85 over white
        assert (np.abs(bottom - blended).max(axis=1) < 0.03).sum() > 500


def test_trajectory_plot_without_gate_and_other_size(tmp_path):
    t, true, sims, _ = _signals()
    path = trajectory_plot(t, true, {"nfir": sims["nfir"]}, None, tmp_path / "a.png", size=(6.0, 4.0), dpi=50)
    assert imread(path).shape[:2] == (200, 300)
    _not_blank(path)


def test_scatter_plot(tmp_path):
    rng = np.random.default_rng(0)
    y = rng.normal(400, 30, 2000)
    path = scatter_plot(y, y + rng.normal(0, 5, y.size), tmp_path / "s.png", title="krls", label="T exhaust")
    img = _not_blank(path)
    assert img.shape[:2] == (600, 600)


@pytest.mark.parametrize("kwargs, fragment", [
    ({"true": np.zeros(5)}, r"true has 5 values but the time axis has 300"),
    ({"gate": np.ones((300, 2, 1))}, r"gate must be \(time steps, experts\) = \(300, M\)"),
    ({"simulated": {"m": np.zeros((300, 2))}}, r"simulated\['m'\] must be one signal"),
    ({"scale": 0.0}, "scale must be a positive number"),
])
def test_bad_inputs_are_refused(tmp_path, kwargs, fragment):
    t, true, sims, gate = _signals()
    args = {"times": t, "true": true, "simulated": sims, "gate": gate, "path": tmp_path / "x.png", **kwargs}
    scale = args.pop("scale", None)
    with pytest.raises(DataError, match=fragment):
        trajectory_plot(**args, scale=scale)
    assert not (tmp_path / "x.png").exists()


def test_plot_run_redraws_a_stored_simulation_run(tmp_path, toy_parquet):
    """End to end: a tiny stored simulation run (NFIR and MoE) -> trajectory PNG with gate bands, scatters."""
    from enginebench.reports.trajectories import plot_run
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench import registry
    from enginebench.methods.nfir import NFIR
    from enginebench.results.store import RunStore

    registry.register(NFIR)
    spec = from_dict({
        "name": "toy-sim", "dataset": str(toy_parquet), "targets": ["y"], "mode": "simulation", "repetitions": 1,
        "train_size": 0, "selection": {"kind": "none"},
        "methods": {"nfir": {"horizons": [2.0], "strides": [1], "gamma_grid": [-1, -1, 1], "lambda_grid": [-2, -2, 1]},
                    "moe": {"cpu_threads": 1}},
    })
    result = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1)
    assert result.n_failed == 0
    report = plot_run(result.run, tmp_path / "fig", trajectories=1)
    names = sorted(p.name for p in report.paths)
    assert names == ["y__w0__s3.png", "y__w0__scatter__moe.png", "y__w0__scatter__nfir.png"], report.notes
    img = _not_blank(tmp_path / "fig" / "y__w0__s3.png")
    assert img.shape[:2] == (700, 1000)
    with pytest.raises(MethodError, match="did not run method\\(s\\) sindy"):
        plot_run(result.run, tmp_path / "fig", methods=["sindy"])


def test_png_trends_draw_the_measured_line_on_top_with_the_unit_on_the_axis():
    from enginebench.reports.plots import trajectory_figure
    from enginebench.reports.refit import Predictions
    from enginebench.reports.static_figures import time_trend_figure

    t = np.arange(100.0)
    preds = [Predictions(target="t_exhaust", window=0.0, split="test", method=m, part="test", repetition=0, time=t,
                         truth=np.sin(t), pred=np.sin(t) + k, segment=np.zeros(100, int))
             for k, m in enumerate(("naive-mean", "ridge"))]
    ax = time_trend_figure(preds, unit="degC").axes[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    assert ax.get_ylabel() == "t_exhaust [degC]" and ax.get_xlabel() == "time since the first test row (s)"
    assert lines["measured"].get_zorder() > max(lines[m].get_zorder() for m in ("naive-mean", "ridge"))
    assert ax.get_legend_handles_labels()[1][0] == "measured"
    ax = trajectory_figure(t, np.sin(t), {"arx": np.cos(t)}, None, ylabel="y", unit="bar").axes[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    assert lines["true"].get_zorder() > lines["arx"].get_zorder() and ax.get_ylabel() == "y [bar]"
