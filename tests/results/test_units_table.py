"""Units everywhere and a terminal table that fits (issue 16, items 1-2).

Headers and axes carry the units a run recorded from its dataset's schema; the terminal
table is one titled block per (target, mode, Delta, split), never wider than asked and
never shortening a name; a diverging method keeps its diverged count beside its numbers.
"""

from __future__ import annotations

import io
import re

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.datasets.dataset import Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.schema import Column, Schema
from enginebench.experiments.runner import run_experiment
from enginebench.method import Method, SegmentPredictions
from enginebench.registry import register
from enginebench.reports.plots import scatter_figure, trajectory_figure
from enginebench.results import tables
from enginebench.results.store import RunStore
from enginebench.results.units import WINDOW, axis_label, header, metric_unit, run_units
from helpers import make_toy, toy_spec

LONG_TARGET = "t_exhaust_turbine_inlet_temperature"
LONG_METHOD = "test-units-runaway-simulator"


@register
class LongNamedRunaway(Method):
    """A simulator with a long name that diverges (1e4 off) on the second test segment of odd repetitions."""

    name = LONG_METHOD
    family = "data-driven"
    modes = frozenset({"simulation"})

    def fit(self, train, params, rng):
        return float(train.y.mean()), int(rng.integers(0, 2))

    def predict(self, fitted, data):
        mean, wild = fitted
        arrays = [np.full((len(s.rows), 1), mean + 1e4 * k * wild) for k, s in enumerate(data.segments)]
        return SegmentPredictions(arrays, [bool(wild and k == 1) for k in range(len(arrays))])


# ----------------------------------------------------------------- the unit helpers
@pytest.mark.parametrize("metric, unit, expected", [
    ("mae", "degC", "mae [degC]"), ("rmse", "kg/h", "rmse [kg/h]"), ("mape", "degC", "mape [%]"),
    ("fit", "degC", "fit [%]"), ("rmae", "mg/m3", "rmae [%]"), ("nrmse", "degC", "nrmse [-]"),
    ("ppmcc", "degC", "ppmcc [-]"), ("skill_mae", "degC", "skill_mae [-]"),
    ("mae", "", "mae"), ("mae", None, "mae"), ("mape", None, "mape [%]"), ("time_fit", "", "time_fit [s]"),
    ("something_new", "degC", "something_new"),
])
def test_header_names_each_metric_with_its_unit(metric, unit, expected):
    assert header(metric, unit) == expected


def test_axis_label_and_run_units():
    assert axis_label("t_exhaust_turbine_inlet", "degC") == "t_exhaust_turbine_inlet [degC]"
    assert axis_label("unit", "") == "unit" and axis_label("x", None) == "x"
    assert run_units({"units": {"y": "degC", "g": ""}}) == {"y": "degC"}
    assert run_units({}) == {} and run_units({"units": "nonsense"}) == {} and run_units(None) == {}
    assert metric_unit("fit_seg_median") == "%" and WINDOW == "Delta [s]"


# ----------------------------------------------------------------- a run remembers its units
@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("units")
    path = write_dataset(make_toy(n=60), tmp / "toy.parquet")
    spec = toy_spec(path, repetitions=2, train_size=0)
    return run_experiment(spec, RunStore(tmp / "runs"), workers=1).run


def _invoke(run, *args, columns: str | None = None):
    env = {"ENGINEBENCH_STORE": str(run.path.parent)}
    if columns:
        env["COLUMNS"] = columns
    out = CliRunner().invoke(cli, ["table", run.id, *args], env=env)
    assert out.exit_code == 0, out.output
    return out.output


def test_a_run_records_the_units_of_its_columns_and_every_format_prints_them(static_run):
    assert static_run.info()["units"] == {"u1": "V", "u2": "bar", "y": "degC"}  # tests/helpers.make_toy's schema
    md = _invoke(static_run, "--format", "md")
    assert md.splitlines()[0] == ("| target | mode | Delta [s] | split | method | n | mae [degC] | mape [%] | ppmcc [-] "
                                  "| rmae [%] |")
    latex = _invoke(static_run, "--format", "latex")
    assert r"target & mode & Delta [s] & split & method & n & mae [degC] & mape [\%] & ppmcc [-] & rmae [\%] \\" in latex
    html_text = _invoke(static_run, "--format", "html")
    assert "<th>Delta [s]</th>" in html_text and "<th>mae [degC]</th>" in html_text and "<th>mape [%]</th>" in html_text
    csv = pd.read_csv(io.StringIO(_invoke(static_run, "--format", "csv")))
    assert list(csv.columns[:8]) == ["dataset", "target", "mode", "Delta [s]", "method", "split", "metric", "unit"]
    units = dict(zip(csv["metric"], csv["unit"].fillna("")))
    assert (units["mae"], units["mape"], units["ppmcc"], units["rmae"], units["skill_mae"]) == ("degC", "%", "-", "%", "-")
    term = _invoke(static_run, "--width", "80")
    assert "y [degC] | static | Delta 0 s | test" in term and "mae [degC]" in term and "mape [%]" in term


def test_an_old_run_without_units_prints_headers_without_them(static_run):
    static_run.update_info(units=None)  # as a run written before units were recorded
    try:
        md = _invoke(static_run, "--format", "md")
        assert md.splitlines()[0] == "| target | mode | Delta [s] | split | method | n | mae | mape [%] | ppmcc [-] | rmae [%] |"
        term = _invoke(static_run, "--width", "80")
        assert "y | static | Delta 0 s | test" in term and re.search(r"\bmae\s", term) and not re.search(r"\bmae \[", term)
    finally:
        static_run.update_info(units={"u1": "V", "u2": "bar", "y": "degC"})


def test_targets_with_different_units_name_their_unit_in_the_row():
    rows = [{"dataset": "d", "target": t, "mode": "static", "window": 0.0, "family": "x", "method": m, "repetition": r,
             "split": "test", "metric": "mae", "value": v + r, "status": "ok"}
            for t in ("egt", "nox") for m, v in (("a", 1.0), ("b", 2.0)) for r in range(3)]
    summary = tables.summarize(pd.DataFrame(rows))
    md = tables.to_markdown(summary, ["mae"], units={"egt": "degC", "nox": "mg/m3"})
    assert md.splitlines()[0] == "| target | mode | Delta [s] | split | method | n | mae [target's unit] |"
    assert "| egt [degC] | static | 0 | test | a |" in md and "| nox [mg/m3] | static | 0 | test | b |" in md
    term = tables.to_term(summary, ["mae"], units={"egt": "degC", "nox": "mg/m3"}, width=80)
    assert "egt [degC] | static | Delta 0 s | test" in term and "nox [mg/m3] | static | Delta 0 s | test" in term


# ----------------------------------------------------------------- the terminal table fits
@pytest.fixture(scope="module")
def long_run(tmp_path_factory):
    """A simulation run of the toy data whose target and one method have names long enough to have been cut."""
    tmp_path = tmp_path_factory.mktemp("long")
    toy = make_toy(n=40)
    frame = toy.frame.rename(columns={"y": LONG_TARGET})
    schema = Schema(tuple(Column(LONG_TARGET if c.name == "y" else c.name, c.role, c.unit) for c in toy.schema.columns))
    meta = {**toy.meta, "published_split": {"train": ["s0", "s1"], "test": ["s2", "s3"]}}
    path = write_dataset(Dataset("toy-long", frame, schema, toy.dt, meta), tmp_path / "long.parquet")
    spec = toy_spec(path, targets=[LONG_TARGET], mode="simulation", repetitions=4, train_size=0,
                    methods={"naive-mean": {}, LONG_METHOD: {}})
    return run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run


def test_the_term_table_fits_80_columns_without_shortening_a_name(long_run):
    run = long_run
    m = run.metrics()
    diverged = int(m[(m["method"] == LONG_METHOD) & (m["metric"] == "diverged")]["value"].sum())
    segments = int(m[(m["method"] == LONG_METHOD) & (m["metric"] == "n_segments")]["value"].sum())
    assert diverged >= 1  # the method does diverge: its count must show
    for text in (_invoke(run, "--width", "80"), _invoke(run, columns="80"),
                 tables.to_term(tables.summarize(m), units=run_units(run.info()), width=80)):
        lines = text.splitlines()
        assert max(len(x) for x in lines) <= 80
        assert "…" not in text
        titles = [x for x in lines if x.startswith(f"{LONG_TARGET} [degC] | simulation | Delta 0 s | test")]
        assert len(titles) >= 2  # rmse, nrmse, fit, rmae do not fit on one 80-column line with these names
        blocks = text.split(f"{LONG_TARGET} [degC] | simulation | Delta 0 s | test")[1:]
        shown = []
        for block in blocks:
            body = block.split("\n\n")[0]
            assert re.search(r"^naive-mean ", body, re.M), body
            row = next(x for x in body.splitlines() if x.startswith(LONG_METHOD + " "))
            assert f"{diverged}/{segments}" in row, row  # the diverged count sits next to the numbers, every block
            shown += [h for h in ("rmse [degC]", "nrmse [-]", "fit [%]", "rmae [%]") if h in body]
        assert sorted(shown) == sorted(["rmse [degC]", "nrmse [-]", "fit [%]", "rmae [%]"])  # each metric once
    wide = _invoke(run, "--width", "200")
    assert max(len(x) for x in wide.splitlines()) <= 200
    assert len([x for x in wide.splitlines() if x.startswith(LONG_TARGET)]) < len(titles)  # more columns a line
    # the table printed at the end of `enginebench run` is the same, at the terminal's width
    assert run.info()["units"][LONG_TARGET] == "degC"


# ----------------------------------------------------------------- plot axes carry units
def test_figure_axes_carry_units_and_normalised_axes_say_so():
    t = np.arange(200) * 0.5
    y = 400 + 10 * np.sin(t / 5)
    fig = trajectory_figure(t, y, {"m": y + 1}, np.full((200, 2), 0.5), inputs={"u1": np.sin(t), "u2": np.cos(t)},
                            ylabel=LONG_TARGET, unit="degC", input_units={"u1": "V", "u2": "bar"},
                            title="a long title " * 20)
    top, ins, gate = fig.axes[:3]
    assert top.get_ylabel() == f"{LONG_TARGET} [degC]"
    assert ins.get_ylabel() == "inputs, standardised\n(z-score) [-]" and gate.get_ylabel() == "gate weight [-]"
    assert [x.get_text() for x in ins.get_legend().get_texts()] == ["u1 [V]", "u2 [bar]"]
    assert fig.axes[2].get_xlabel() == "time [s]"
    fig.canvas.draw()  # the wrapped title stays inside the figure
    box, page = top.title.get_window_extent(), fig.bbox
    assert box.x0 >= page.x0 and box.x1 <= page.x1
    scaled = trajectory_figure(t, y, {"m": y + 1}, None, ylabel="WF", unit="kg/h", scale=412.0)
    assert scaled.axes[0].get_ylabel() == "WF\nnormalised [-]: divided by its\ntraining mean |y| = 412 kg/h"
    scaled.canvas.draw()  # the three short lines fit the panel's height
    box, axes_box = scaled.axes[0].yaxis.label.get_window_extent(), scaled.axes[0].get_window_extent()
    assert box.y0 >= axes_box.y0 - 1 and box.y1 <= axes_box.y1 + 1
    sc = scatter_figure(y, y + 1, label="WF", unit="kg/h")
    assert (sc.axes[0].get_xlabel(), sc.axes[0].get_ylabel()) == ("measured WF [kg/h]", "predicted WF [kg/h]")
    assert scatter_figure(y, y, label="WF").axes[0].get_xlabel() == "measured WF"  # no unit known


def test_plot_run_labels_read_the_units_the_run_recorded(long_run, tmp_path, monkeypatch):
    from enginebench.reports import trajectories

    run = long_run
    figures = []

    def keep(make):
        def draw(*args, **kwargs):
            path = args[-1] if make is trajectory_figure else args[2]
            args = args[:-1] if make is trajectory_figure else args[:2]
            figures.append(make(*args, **kwargs))
            return path
        return draw

    monkeypatch.setattr(trajectories, "trajectory_plot", keep(trajectory_figure))
    monkeypatch.setattr(trajectories, "scatter_plot", keep(scatter_figure))
    trajectories.plot_run(run, tmp_path / "fig", trajectories=1)
    labels = {ax.get_ylabel() for fig in figures for ax in fig.axes} | {ax.get_xlabel() for fig in figures for ax in fig.axes}
    assert f"{LONG_TARGET}\nnormalised [-]: divided by its\ntraining mean |y| = " in "\n".join(labels)
    assert f"measured {LONG_TARGET} [degC]" in labels and f"predicted {LONG_TARGET} [degC]" in labels
    legends = {t.get_text() for fig in figures for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()}
    assert {"u1 [V]", "u2 [bar]"} <= legends


def test_the_egt_hybrid_layout_heads_its_columns_with_units():
    from enginebench.results.layouts import egt_hybrid_markdown, egt_hybrid_table

    rows = [{"target": "t_exh", "mode": "window", "window": 5.0, "method": "krls", "split": "test", "metric": m,
             "value": v + 0.1 * r, "repetition": r, "status": "ok"}
            for m, v in (("mae", 2.0), ("mape", 0.5), ("ppmcc", 0.9)) for r in range(3)]
    table = egt_hybrid_table(pd.DataFrame(rows), literature=False)
    md = egt_hybrid_markdown(table, units={"t_exh": "degC"}).splitlines()
    assert md[0] == "### t_exh [degC]"
    assert md[2] == "| Δ [s] | model | source | MAE [degC] | MAPE [%] | PPMCC [-] | n |"
    assert md[4].startswith("| 5 | krls | this run | 2.1 ± 0.25 | 0.6 ± 0.25 | 1 ± 0.25 | 3 |")
    assert egt_hybrid_markdown(table).splitlines()[2] == "| Δ [s] | model | source | MAE | MAPE [%] | PPMCC [-] | n |"
