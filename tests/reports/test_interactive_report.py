"""The interactive report (report.html): self-contained, units, diverged traces, failures, and a real browser."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.errors import MethodError
from enginebench.method import EXPLAIN_WEIGHTS, Method, Params, SegmentPredictions
from enginebench.results.store import RunStore
from enginebench.samples import Samples
from helpers import make_toy

plotly = pytest.importorskip("plotly", reason="plotly is the optional extra 'report' (pip install enginebench[report])")

from enginebench.reports import interactive_figures as ia  # noqa: E402
from enginebench.reports.interactive import (  # noqa: E402
    INSTALL_HINT, run_units, write_interactive_report, write_reports)
from enginebench.results.units import axis_label  # noqa: E402

FAIL_REASON = "intentional failure of the test method"


class GatedMean(Method):
    """Training mean, two 'experts' mixed by a weight that ramps over each segment; the last segment diverges."""

    name = "test-gated"
    modes = frozenset({"simulation"})

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> np.ndarray:
        return train.y.mean(axis=0)

    def predict(self, fitted: np.ndarray, data: Samples) -> SegmentPredictions:
        arrays = [np.broadcast_to(fitted + 0.1 * np.arange(len(s))[:, None] / len(s), (len(s), fitted.size)).copy()
                  for s in data.segments]
        return SegmentPredictions(arrays, [k == len(arrays) - 1 for k in range(len(arrays))])

    def explain(self, fitted: np.ndarray, data: Samples) -> dict[str, list[np.ndarray]]:
        ramps = [np.linspace(0.0, 1.0, len(s)) for s in data.segments]
        return {EXPLAIN_WEIGHTS: [np.column_stack([r, 1.0 - r]) for r in ramps]}


class Boom(Method):
    """Fails on every fit, so the run has failed jobs with a reason."""

    name = "test-boom"
    modes = frozenset({"simulation"})

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> None:
        raise MethodError(FAIL_REASON)

    def predict(self, fitted: None, data: Samples) -> list[np.ndarray]:  # pragma: no cover - never fitted
        raise MethodError(FAIL_REASON)


def _run(root: Path, **changes):
    from enginebench.datasets.io import write_dataset
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict

    toy = make_toy(n_segments=5, n=100)
    toy.meta["published_split"] = {"train": ["s0", "s1", "s2"], "test": ["s3", "s4"]}
    data = write_dataset(toy, root / "toy.parquet")
    raw = {"name": "toy-interactive", "dataset": str(data), "targets": ["y"], "repetitions": 2, "seed": 3,
           "train_size": 120, "selection": {"kind": "bootstrap", "resamples": 2},
           "methods": {"naive-mean": {}, "krls": {"gamma_grid": [-2, 0, 3], "lambda_grid": [-3, -1, 3]}}}
    raw.update(changes)
    return run_experiment(from_dict(raw, origin="test"), RunStore(root / "runs"), workers=1).run


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("static"))


@pytest.fixture(scope="module")
def simulation_run(tmp_path_factory):
    from enginebench import registry

    registry.register(GatedMean)
    registry.register(Boom)
    return _run(tmp_path_factory.mktemp("simulation"), mode="simulation", repetitions=1, train_size=0,
                selection={"kind": "none"}, methods={"naive-mean": {}, "test-gated": {}, "test-boom": {}})


@pytest.fixture(scope="module")
def static_pages(static_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("static-report")
    return out, write_reports(static_run, out)


@pytest.fixture(scope="module")
def simulation_pages(simulation_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("simulation-report")
    return out, write_reports(simulation_run, out, trajectories=2)


class _Tags(HTMLParser):
    """Every start tag's attributes, and the figure data embedded in the drawing scripts."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.scripts: list[str] = []
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        self._in_script = tag == "script"

    def handle_endtag(self, tag):
        self._in_script = False

    def handle_data(self, data):
        if self._in_script:
            self.scripts.append(data)


def _parse(text: str) -> _Tags:
    parser = _Tags()
    parser.feed(text)
    return parser


def _figures(text: str) -> list[dict]:
    """The figure JSON of each ``Plotly.newPlot(id, data, layout, config)`` call on the page."""
    import json

    decoder = json.JSONDecoder()
    out = []
    for script in _parse(text).scripts:
        for m in re.finditer(r'Plotly\.newPlot\(\s*"[^"]+",\s*', script):
            data, end = decoder.raw_decode(script, m.end())
            layout, _ = decoder.raw_decode(script, script.index("{", end))
            out.append({"data": data, "layout": layout})
    return out


def _values(v) -> np.ndarray:
    """A trace's x/y as floats: a JSON list, or plotly's typed array ({"dtype", "bdata"} base64)."""
    import base64

    if isinstance(v, dict):
        flat = np.frombuffer(base64.b64decode(v["bdata"]), dtype=np.dtype(v["dtype"]))
        return flat.reshape(v["shape"]) if "shape" in v and isinstance(v["shape"], list) else flat.astype(float)
    return np.asarray([np.nan if x is None else x for x in v], dtype=float)


# -- the file -------------------------------------------------------------------------

def test_page_is_one_self_contained_file_with_plotly_inlined_once(static_pages):
    from plotly.offline import get_plotlyjs

    out, (static, page, notes) = static_pages
    assert page.path == out / "report.html" and static.index == out / "index.html"
    text = page.path.read_text()
    banner = get_plotlyjs()[:300]
    assert text.count(banner) == 1  # plotly.js inlined exactly once
    tags = _parse(text).tags
    sources = [a.get(k, "") for t, a in tags if t in ("script", "link", "img", "iframe") for k in ("src", "href")]
    assert not [s for s in sources if s]  # no external script, stylesheet, image or frame at all
    links = [a["href"] for t, a in tags if t == "a" and "href" in a]
    assert not [h for h in links if re.match(r"(https?:)?//", h)], links
    assert '<a href="report.html">report.html</a>' in static.index.read_text()  # the static page links to it
    # trend, scatter, 4 metrics per repetition, krls's validation curve (naive-mean searches nothing)
    assert len(_figures(text)) == len(page.figures) == 7
    assert page.figures[-1].startswith("krls: y, window 0 s, split published: validation score")



def test_validation_curve_stars_the_hyperparameters_each_repetition_selected(static_pages, static_run):
    _, (_, page, _) = static_pages
    curve = _figures(page.path.read_text())[-1]
    stars = curve["data"][-1]
    table = static_run.selection_table()
    table = table[table["method"] == "krls"]
    # the x axis is the hyperparameter with the most values tried (the grid and its extension past the edges)
    most = max(("gamma", "lambda"), key=lambda p: table[f"param:{p}"].nunique())
    assert stars["name"] == "chosen (per repetition)" and curve["layout"]["xaxis"]["title"]["text"] == most
    reps = _values(stars["customdata"]).astype(int)
    selected = [static_run.job_meta(f"y__w0__published__krls__r{r:03d}")["params"][most] for r in reps]
    np.testing.assert_allclose(_values(stars["x"]), selected)
    assert sorted(reps) == [0, 1] and curve["layout"]["xaxis"]["type"] == "log"  # positive over decades


def test_time_series_and_scatter_carry_the_refitted_predictions(static_pages, static_run):
    _, (static, page, _) = static_pages
    figs = _figures(page.path.read_text())
    series, scatter = figs[0], figs[1]
    names = [t["name"] for t in series["data"]]
    assert names == ["naive-mean", "krls", "measured"]  # the measured trace drawn last: on top of every model
    assert min(series["data"], key=lambda t: t["legendrank"])["name"] == "measured"  # and first in the legend
    preds = {p.method: p for p in static.predictions}
    krls = _values(series["data"][1]["y"])
    # the test part's two segments are separated by one NaN: no line joins them
    assert len(krls) == len(preds["krls"].pred) + 1 and np.isnan(krls).sum() == 1
    np.testing.assert_allclose(krls[~np.isnan(krls)], preds["krls"].pred)
    assert [t["name"] for t in scatter["data"]] == ["naive-mean", "krls", "identity"]
    np.testing.assert_allclose(_values(scatter["data"][1]["x"]), preds["krls"].truth)
    label = axis_label("y", run_units(static_run).get("y"))
    assert series["layout"]["yaxis"]["title"]["text"] == label
    assert scatter["layout"]["xaxis"]["title"]["text"] == f"measured {label}"


def test_table_is_sortable_and_lists_every_method(static_pages):
    _, (_, page, _) = static_pages
    text = page.path.read_text()
    assert '<table class="sortable">' in text and ia.SORT_SCRIPT in text
    head = re.search(r'<table class="sortable">\n<thead><tr>(.*?)</tr>', text).group(1)
    cols = re.findall(r"<th[^>]*>(.*?)</th>", head)
    assert cols[:6] == ["target", "mode", "Delta [s]", "split", "method", "n"]
    assert cols[6].startswith("mae") and cols[7] == "mape [%]"
    body = re.search(r'<table class="sortable">.*?<tbody>(.*?)</tbody>', text, re.S).group(1)
    assert sorted(re.findall(r"<td>(krls|naive-mean)</td>", body)) == ["krls", "naive-mean"]


def test_simulation_page_marks_divergence_draws_the_weights_and_lists_failures(simulation_pages, simulation_run):
    _, (static, page, notes) = simulation_pages
    text = page.path.read_text()
    assert f"failed (1 job): test-boom: MethodError: {FAIL_REASON}" in text or f"test-boom: {FAIL_REASON}" in text
    series = _figures(text)[0]
    traces = {t["name"]: t for t in series["data"]}
    assert set(traces) == {"measured", "naive-mean", "test-gated", "test-gated (diverged)", "expert 1", "expert 2"}
    assert traces["test-gated (diverged)"]["line"]["dash"] == "dash"
    assert traces["test-gated"]["line"]["dash"] == "solid"
    assert traces["test-gated (diverged)"]["legendgroup"] == traces["test-gated"]["legendgroup"]  # toggled together
    sim = static.simulated[0]
    last = _values(traces["test-gated (diverged)"]["y"])
    np.testing.assert_allclose(last, sim.sims["test-gated"][-1])  # exactly the diverged (last) trajectory
    gate = [traces["expert 1"], traces["expert 2"]]
    assert {g["stackgroup"] for g in gate} == {"weights"} and {g["yaxis"] for g in gate} == {"y2"}
    total = np.nansum([_values(g["y"]) for g in gate], axis=0)
    np.testing.assert_allclose(total[np.isfinite(total) & (total > 0)], 1.0)
    # the legend lists measured, the methods, then the weights' group (it sat between two methods)
    ranked = [t["name"] for t in sorted(series["data"], key=lambda t: t["legendrank"])]
    assert ranked[0] == "measured" and ranked[-2:] == ["expert 1", "expert 2"]
    assert "test-gated mixing weights as bands underneath" in text
    assert "diverged (dashed): test-gated (1 segment)" in text
    assert any("test-boom: not drawn" in n for n in page.notes)


# -- pure builders --------------------------------------------------------------------

def test_minmax_decimation_keeps_each_buckets_extremes_within_segments():
    rng = np.random.default_rng(0)
    values = rng.normal(size=1003)
    values[517] = 50.0  # a spike that striding would miss
    values[40] = np.nan
    segment = np.repeat([0, 1, 2], [400, 600, 3])
    rows = ia.minmax_rows(values, segment, 7)
    expected = []
    for s in range(3):
        idx = np.flatnonzero(segment == s)
        for chunk in np.array_split(idx, np.arange(7, idx.size, 7)):
            v = values[chunk]
            expected += [chunk[np.nanargmin(v)], chunk[np.nanargmax(v)]]
    np.testing.assert_array_equal(rows, np.unique(expected))
    assert 517 in rows and 40 not in rows
    assert ia.decimation_factor(1003, 20_000) == 1 and ia.decimation_factor(100_000, 20_000) == 10
    starts, means = ia.bucket_means(np.column_stack([values * 0 + 0.25, values * 0 + 0.75]), segment, 7)
    assert starts[0] == 0 and 400 in starts  # buckets restart at every segment
    np.testing.assert_allclose(np.nansum(means, axis=1)[~np.isnan(means).any(axis=1)], 1.0)


def test_time_series_figure_decimates_says_so_and_puts_units_on_the_axes():
    n = 50_000
    x = np.arange(n) / 3600.0
    segment = np.repeat([0, 1], n // 2)
    measured = np.sin(np.arange(n) / 500.0)
    fig = ia.time_series_figure(x, segment, measured, {"m": measured + 0.1}, diverged={"m": segment == 1},
                                title="t", x_label="time (h)", y_label=axis_label("t_exhaust", "degC"),
                                max_points=20_000)
    data = ia.figure_json(fig)
    assert data["layout"]["yaxis"]["title"]["text"] == "t_exhaust [degC]"
    assert "min/max decimation 1:5" in data["layout"]["title"]["text"]
    lengths = {t["name"]: len(_values(t["y"])) for t in data["data"]}
    assert lengths["measured"] <= 20_000 + 1 and lengths["m"] <= 10_000 and lengths["m (diverged)"] <= 10_000
    assert [t["line"]["dash"] for t in data["data"]] == ["solid", "dash", "solid"]
    assert data["data"][-1]["name"] == "measured"  # drawn over the models
    # more than WEBGL_POINTS points: every line is WebGL alike (a mix would draw the GL lines over the SVG ones)
    assert {t["type"] for t in data["data"]} == {"scattergl"}
    assert {t["y"]["dtype"] for t in data["data"]} == {"f4"}  # float32 on the page


def test_long_records_are_decimated_to_max_points_and_short_ones_stay_svg():
    n = 100_000
    x = np.arange(n, dtype=float)
    segment = np.zeros(n, int)
    measured = np.sin(x / 50.0)
    data = ia.figure_json(ia.time_series_figure(x, segment, measured, {"m": measured}))
    assert all(len(_values(t["y"])) <= ia.MAX_POINTS + 1 for t in data["data"])
    assert {t["type"] for t in data["data"]} == {"scattergl"}
    scatter = ia.figure_json(ia.scatter_figure(measured, {"m": measured}))
    assert len(_values(scatter["data"][0]["x"])) == ia.MAX_POINTS and scatter["data"][0]["type"] == "scattergl"
    small = ia.figure_json(ia.time_series_figure(x[:500], segment[:500], measured[:500], {"m": measured[:500]}))
    assert {t["type"] for t in small["data"]} == {"scatter"} and small["data"][-1]["name"] == "measured"


def test_validation_figure_draws_the_grid_mean_and_the_chosen_points():
    grid = [(g, lam) for g in (0.01, 1.0, 100.0) for lam in (1e-3, 1e-1)]
    rows = []
    for rep in range(2):
        for point, (g, lam) in enumerate(grid):
            for resample in range(2):
                rows.append({"target": "y", "window": 0.0, "split": "test", "method": "krls", "repetition": rep,
                             "point": point, "param:gamma": g, "param:lambda": lam, "resample": resample,
                             "score": g + lam + resample + rep, "criterion": "mse", "chosen": point == 0})
    fig = ia.figure_json(ia.validation_figure(pd.DataFrame(rows), title="krls"))
    lines = [t for t in fig["data"] if t["mode"] == "lines+markers"]
    assert [t["name"] for t in lines] == ["lambda=0.001", "lambda=0.1"]
    np.testing.assert_allclose(_values(lines[0]["y"]), [0.01 + 0.001 + 1.0, 1.0 + 0.001 + 1.0, 100 + 0.001 + 1.0])
    stars = fig["data"][-1]
    assert stars["marker"]["symbol"] == "star" and list(_values(stars["customdata"])) == [0, 1]
    assert fig["layout"]["xaxis"]["type"] == "log" and fig["layout"]["yaxis"]["title"]["text"] == "validation mse"
    assert ia.validation_figure(pd.DataFrame(rows).assign(**{"param:gamma": 1.0, "param:lambda": 1.0})) is None
    narrow = pd.DataFrame(rows).assign(**{"param:gamma": lambda f: f["param:gamma"].map({0.01: 1.0, 1.0: 2.0,
                                                                                          100.0: 9.0})})
    assert ia.figure_json(ia.validation_figure(narrow))["layout"]["xaxis"]["type"] == "linear"  # under a decade


def test_sortable_table_escapes_and_refuses_ragged_rows():
    text = ia.sortable_table(["a", "b<"], [["1", "<x>"]], [[True, False]])
    assert "<th title=\"click to sort\">b&lt;</th>" in text and "<td><b>1</b></td><td>&lt;x&gt;</td>" in text
    with pytest.raises(Exception, match="row 0 has 1 cells but there are 2 headers"):
        ia.sortable_table(["a", "b"], [["1"]])


# -- command line ---------------------------------------------------------------------

def test_report_command_writes_both_pages_and_says_how_to_get_plotly(static_run, tmp_path, monkeypatch):
    runner = CliRunner()
    store = str(static_run.path.parent)
    out = tmp_path / "cli"
    res = runner.invoke(cli, ["report", static_run.id, "-o", str(out), "--store", store, "--no-figures"])
    assert res.exit_code == 0, res.output  # no re-fit: the table, 4 metrics per repetition, 1 validation curve
    assert res.output.strip().splitlines() == [f"wrote {out / 'index.html'} (0 figures)",
                                               f"wrote {out / 'report.html'} (interactive, 5 figures)"]
    res = runner.invoke(cli, ["report", static_run.id, "-o", str(tmp_path / "no"), "--store", store, "--no-figures",
                              "--no-interactive"])
    assert res.exit_code == 0 and not (tmp_path / "no" / "report.html").exists()
    assert "report.html" not in (tmp_path / "no" / "index.html").read_text()
    monkeypatch.setattr("enginebench.reports.interactive.plotly_available", lambda: False)
    res = runner.invoke(cli, ["report", static_run.id, "-o", str(tmp_path / "bare"), "--store", store, "--no-figures"])
    assert res.exit_code == 0
    assert res.output.strip().splitlines() == [
        f"note: interactive report (report.html) not written: plotly is not installed; {INSTALL_HINT}",
        f"wrote {tmp_path / 'bare' / 'index.html'} (0 figures)"]


def test_standalone_writer_refits_like_the_static_report(static_run, static_pages, tmp_path):
    _, (_, page, _) = static_pages
    alone = write_interactive_report(static_run, tmp_path / "alone.html")
    assert alone.figures == page.figures
    assert _figures(alone.path.read_text())[0]["data"] == _figures(page.path.read_text())[0]["data"]


# -- a real browser -------------------------------------------------------------------

def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def render(path: Path, tmp: Path) -> tuple[str, list[str]]:
    """(the DOM after scripts ran, console messages) of ``path`` in headless Chromium."""
    cmd = [_chromium(), "--headless=new", "--disable-gpu", "--no-sandbox", "--enable-logging=stderr", "--v=0",
           "--virtual-time-budget=10000", f"--user-data-dir={tmp / 'profile'}", "--dump-dom", path.as_uri()]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env={**os.environ, "HOME": str(tmp)})
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout, [ln for ln in done.stderr.splitlines() if ":CONSOLE" in ln]


class _Classes(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.classes: list[set[str]] = []

    def handle_starttag(self, tag, attrs):
        self.classes.append(set((dict(attrs).get("class") or "").split()))


def _count(dom: str, cls: str) -> int:
    parser = _Classes()
    parser.feed(dom)
    return sum(cls in c for c in parser.classes)


browser = pytest.mark.skipif(_chromium() is None, reason="no chromium on PATH (apt-get install chromium); the "
                                                          "browser test needs a real headless browser")


@browser
def test_console_capture_sees_errors(tmp_path):
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><script>console.error('boom here'); missingFunction();</script></body></html>")
    _, console = render(bad, tmp_path)
    assert any("boom here" in ln for ln in console) and any("missingFunction" in ln for ln in console)


@browser
@pytest.mark.parametrize("which", ["static_pages", "simulation_pages"])
def test_report_renders_in_headless_chromium_without_console_messages(which, request, tmp_path):
    _, (_, page, _) = request.getfixturevalue(which)
    dom, console = render(page.path, tmp_path)
    assert console == []  # no error, no warning, nothing logged at all
    assert _count(dom, "js-plotly-plot") == len(page.figures) > 0  # every figure was drawn by plotly.js
    assert _count(dom, "main-svg") >= len(page.figures)


@browser
def test_clicking_a_header_sorts_the_table_by_value(tmp_path):
    table = ia.sortable_table(["method", "mae"], [["a", "10.5 ± 1"], ["b", "n/a"], ["c", "2 ± 0.1"], ["d", "0.3"]])
    page = tmp_path / "sort.html"
    clicks = "<script>var h = document.querySelectorAll('th'); h[1].click(); document.body.dataset.asc = " \
             "Array.from(document.querySelectorAll('tbody tr td:first-child')).map(c => c.textContent).join(); " \
             "h[1].click();</script>"
    page.write_text(f"<html><body>{table}{ia.SORT_SCRIPT}{clicks}</body></html>")
    dom, console = render(page, tmp_path)
    assert console == []
    assert 'data-asc="d,c,a,b"' in dom  # by number (0.3 < 2 < 10.5, not as text), "n/a" last
    rows = re.findall(r"<tr><td>(\w)</td>", dom)
    assert rows == ["a", "c", "d", "b"]  # the second click sorts descending, "n/a" still last


def test_simulation_page_maps_each_methods_error_over_the_first_two_inputs(simulation_pages):
    from enginebench.reports.operating_map import operating_map

    _, (static, page, _notes) = simulation_pages
    text = page.path.read_text()
    assert "Error over the operating map" in text
    sim = static.simulated[0]
    names = list(sim.train_inputs)[:2]
    maps = [f for f in _figures(text) if "free-run error over" in str(f["layout"].get("title", ""))]
    assert len(maps) == 1
    heat = [t for t in maps[0]["data"] if t["type"] == "heatmap"]
    assert len(heat) == 1 + len(sim.sims)  # training rows, then one RMSE map per method drawn
    x, y = (np.concatenate([seg[n] for seg in sim.inputs]) for n in names)
    expected = operating_map(x, y, np.concatenate(sim.truth), {k: np.concatenate(v) for k, v in sim.sims.items()},
                             sim.train_inputs[names[0]], sim.train_inputs[names[1]])
    got = np.array(_values(heat[1]["z"]) if not isinstance(heat[1]["z"], list) else heat[1]["z"], dtype=float)
    np.testing.assert_allclose(got.reshape(10, 10), expected.rmse[list(sim.sims)[0]], equal_nan=True)


def test_every_axis_of_the_page_names_its_unit(simulation_pages, simulation_run):
    """Time series (value and time), scatters, metrics per repetition, operating map (both inputs) and validation
    scores carry the unit the run recorded for their column."""
    _, (_, page, _) = simulation_pages
    units = run_units(simulation_run)
    figs = _figures(page.path.read_text())
    titles = [(ax, f["layout"][ax]["title"]["text"]) for f in figs for ax in f["layout"]
              if ax.startswith(("xaxis", "yaxis")) and (f["layout"][ax].get("title") or {}).get("text")]
    assert titles
    for ax, title in titles:
        assert re.search(r"\[[^\]]+\]|\((s|min|h|days)\)", title), (ax, title)
    maps = [f for f in figs if "free-run error over" in str(f["layout"].get("title", ""))]
    x_title = maps[0]["layout"]["xaxis"]["title"]["text"]
    name = x_title.split(" [")[0]
    assert x_title == axis_label(name, units[name])


def test_validation_scores_and_operating_map_axes_take_the_given_units():
    from enginebench.reports.operating_map import operating_map

    rows = [{"repetition": 0, "point": i, "param:gamma": g, "resample": 0, "score": g, "criterion": "mae",
             "chosen": i == 0} for i, g in enumerate((0.1, 1.0, 10.0))]
    fig = ia.figure_json(ia.validation_figure(pd.DataFrame(rows), title="krls", unit="degC"))
    assert fig["layout"]["yaxis"]["title"]["text"] == "validation mae [degC]"
    rng = np.random.default_rng(0)
    a, b = rng.uniform(0, 1, 200), rng.uniform(0, 1, 200)
    m = operating_map(a, b, a + b, {"m": a}, a, b, names=("speed", "load"))
    fig = ia.figure_json(ia.operating_map_figure(m, unit="kN m", axis_units={"speed": "rpm", "load": "%"}))
    assert fig["layout"]["xaxis"]["title"]["text"] == "speed [rpm]"
    assert fig["layout"]["yaxis"]["title"]["text"] == "load [%]"


def test_segments_overlapping_in_time_are_laid_end_to_end_and_others_keep_their_times():
    """Two engines of one flight cover the same seconds: the time series lays them end to end (one median sample
    period apart) so that neither is drawn over the other; segments already in sequence keep their times."""
    from enginebench.reports.interactive import end_to_end

    t = np.r_[np.arange(10.0, 15.0), np.arange(10.0, 15.0)]
    seg = np.repeat([0, 1], 5)
    out, moved = end_to_end(t, seg)
    assert moved and out.tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    seq = np.r_[np.arange(0.0, 5.0), np.arange(100.0, 103.0)]
    out, moved = end_to_end(seq, np.repeat([0, 1], [5, 3]))
    assert not moved and np.array_equal(out, seq)
