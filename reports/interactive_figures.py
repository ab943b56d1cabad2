"""Interactive figures (plotly) and HTML fragments of a run's results, from plain arrays and frames.

Pure functions: data in, a ``plotly.graph_objects.Figure`` or an HTML string out; no run,
dataset or method is read here (``reports.interactive`` assembles the page).
Long records are decimated for the browser by keeping each bucket's minimum and maximum
row (``minmax_rows``), so spikes survive where striding would drop them; the factor is
said in the figure's subtitle. Traces of more than ``WEBGL_POINTS`` points are drawn with
WebGL (``scattergl``), every line of a panel alike, and the numbers travel as float32 (a
plot's 4 significant digits need no more), so a long record's page stays light. The
measured trace is added last, so it is drawn on top of every model (first in the legend
all the same). plotly is the optional extra ``report``.
"""

from __future__ import annotations

import html
import json
import math
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from enginebench.errors import DataError

MAX_POINTS = 5_000
"""Most points per trace sent to the browser (time series and scatters): 2,500 min/max buckets, two per pixel
column of a wide figure."""
WEBGL_POINTS = 1_000
"""Traces of more points are drawn with WebGL (``scattergl``): SVG slows down past a few thousand points."""
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
           "#bcbd22", "#17becf")
DIVERGED = "(diverged)"
PARAM_PREFIX = "param:"
PLOT_CONFIG = {"displaylogo": False, "responsive": True}


# -- decimation -----------------------------------------------------------------------

def decimation_factor(n: int, max_points: int = MAX_POINTS) -> int:
    """Rows per bucket so that keeping 2 rows (min, max) per bucket leaves at most about ``max_points``."""
    if max_points < 2:
        raise DataError(f"max_points must be >= 2, got {max_points}")
    return 1 if n <= max_points else int(math.ceil(2 * n / max_points))


def _buckets(segment: np.ndarray, factor: int) -> np.ndarray:
    """Bucket id per row: ``factor`` consecutive rows of one segment (a bucket never spans two segments)."""
    n = segment.size
    new_segment = np.r_[True, segment[1:] != segment[:-1]] if n else np.zeros(0, bool)
    starts = np.flatnonzero(new_segment)
    local = np.arange(n) - np.repeat(starts, np.diff(np.r_[starts, n]))
    return np.cumsum(local % factor == 0) - 1


def _first_per_bucket(order: np.ndarray, bucket: np.ndarray) -> np.ndarray:
    b = bucket[order]
    return order[np.r_[True, b[1:] != b[:-1]]] if order.size else order


def minmax_rows(values: np.ndarray, segment: np.ndarray, factor: int) -> np.ndarray:
    """Sorted row indices keeping each bucket's minimum and maximum row (all rows when ``factor`` <= 1).

    Buckets are ``factor`` consecutive rows within one segment. NaN rows are neither a
    minimum nor a maximum unless the whole bucket is NaN (then its first row is kept).
    """
    v = np.asarray(values, dtype=float)
    seg = np.asarray(segment)
    if v.shape != seg.shape or v.ndim != 1:
        raise DataError(f"decimation: values {v.shape} and segment {seg.shape} must be equally long 1-D arrays")
    if factor <= 1:
        return np.arange(v.size)
    bucket = _buckets(seg, factor)
    nan = np.isnan(v)
    lows = _first_per_bucket(np.lexsort((np.where(nan, np.inf, v), bucket)), bucket)
    highs = _first_per_bucket(np.lexsort((np.where(nan, np.inf, -v), bucket)), bucket)
    return np.union1d(lows, highs)


def bucket_means(values: np.ndarray, segment: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """(first row of each bucket, (buckets, k) means of ``values`` over it): rows summing to 1 still do."""
    w = np.asarray(values, dtype=float)
    w = w[:, None] if w.ndim == 1 else w
    if factor <= 1:
        return np.arange(w.shape[0]), w
    bucket = _buckets(np.asarray(segment), factor)
    starts = np.flatnonzero(np.r_[True, bucket[1:] != bucket[:-1]])
    sums = np.add.reduceat(w, starts, axis=0)
    return starts, sums / np.diff(np.r_[starts, w.shape[0]])[:, None]


def gapped(x: np.ndarray, y: np.ndarray, segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x``, ``y`` with one NaN inserted between consecutive segments, so no line joins them."""
    breaks = np.flatnonzero(segment[1:] != segment[:-1]) + 1
    return (np.insert(np.asarray(x, dtype=float), breaks, np.nan),
            np.insert(np.asarray(y, dtype=float), breaks, np.nan))


# -- figures --------------------------------------------------------------------------

def _go():
    import plotly.graph_objects as go

    return go


def _title(text: str, subtitle: str = "") -> dict:
    sub = f"<br><span style='font-size:12px;color:#555'>{html.escape(subtitle)}</span>" if subtitle else ""
    return {"text": html.escape(text) + sub, "x": 0.01, "xanchor": "left"}


def _f32(values: np.ndarray) -> np.ndarray:
    """``values`` as float32: half the page's bytes; a plotted number shows 4 significant digits."""
    return np.asarray(values, dtype=np.float32)


def _scatter_type(go, points: int):
    """``go.Scattergl`` for a trace of more than ``WEBGL_POINTS`` points, else ``go.Scatter`` (SVG)."""
    return go.Scattergl if points > WEBGL_POINTS else go.Scatter


def _line_traces(go, x, y, segment, rows, name, color, dash, group, showlegend=True, kind=None, **extra):
    xs, ys = gapped(x[rows], y[rows], segment[rows])
    kind = kind or go.Scatter
    return kind(x=_f32(xs), y=_f32(ys), mode="lines", name=name, legendgroup=group, showlegend=showlegend,
                line={"color": color, "width": 1.1 if dash == "solid" else 1.4, "dash": dash}, **extra)


def time_series_figure(
    x: np.ndarray,
    segment: np.ndarray,
    measured: np.ndarray,
    predicted: Mapping[str, np.ndarray],
    *,
    diverged: Mapping[str, np.ndarray] | None = None,
    weights: np.ndarray | None = None,
    weights_label: str = "",
    title: str = "",
    x_label: str = "time",
    y_label: str = "output",
    max_points: int = MAX_POINTS,
):
    """Measured and predicted over time, one trace per method (a legend click toggles it).

    ``x``, ``segment``, ``measured`` and each predicted array share the rows; lines break
    between segments. ``diverged[method]`` (per row) moves that method's diverged
    segments to a dashed trace named "METHOD (diverged)" in the same legend group.
    ``weights`` (rows, k) become a stacked area subplot underneath (bucket means when
    decimated). Each trace keeps at most about ``max_points`` rows (``minmax_rows``);
    the factor is said in the subtitle. Lines are WebGL traces when they hold more than
    ``WEBGL_POINTS`` points (all of them alike, so the measured one stays on top); the
    measured trace is the last one drawn and the first in the legend.
    """
    go = _go()
    x = np.asarray(x, dtype=float)
    segment = np.asarray(segment)
    n = x.size
    for name, arr in {"measured": measured, **predicted}.items():
        if np.shape(arr) != (n,):
            raise DataError(f"time series: {name!r} has shape {np.shape(arr)}; expected ({n},) like the time axis")
    factor = decimation_factor(n, max_points)
    subtitle = (f"{n} rows; min/max decimation 1:{factor} per trace (each {factor}-row bucket keeps its "
                "lowest and highest row); zoom with the mouse, click a legend entry to hide it" if factor > 1 else
                f"{n} rows, all drawn; zoom with the mouse, click a legend entry to hide it")
    rows_panel = 2 if weights is not None else 1
    if rows_panel == 2:
        from plotly.subplots import make_subplots

        fig = make_subplots(rows=2, cols=1, shared_xaxes=True, row_heights=[0.72, 0.28], vertical_spacing=0.05)
    else:
        fig = go.Figure()
    add = (lambda t: fig.add_trace(t, row=1, col=1)) if rows_panel == 2 else fig.add_trace
    measured = np.asarray(measured, dtype=float)
    measured_rows = minmax_rows(measured, segment, factor)
    kind = _scatter_type(go, len(measured_rows))
    for k, (name, values) in enumerate(predicted.items()):
        values = np.asarray(values, dtype=float)
        color = PALETTE[k % len(PALETTE)]
        bad = np.zeros(n, bool) if diverged is None or diverged.get(name) is None else np.asarray(diverged[name], bool)
        for flag, label, dash in ((False, name, "solid"), (True, f"{name} {DIVERGED}", "dash")):
            keep = np.flatnonzero(bad == flag)
            if keep.size == 0:
                continue
            rows = keep[minmax_rows(values[keep], segment[keep], factor)]
            add(_line_traces(go, x, values, segment, rows, label, color, dash, name, kind=kind, legendrank=1000 + k))
    # last, so it is drawn over every model; legendrank keeps it first in the legend
    add(_line_traces(go, x, measured, segment, measured_rows, "measured", "black", "solid", "measured", kind=kind,
                     legendrank=1))
    if weights is not None:
        w = np.asarray(weights, dtype=float)
        if w.ndim != 2 or w.shape[0] != n:
            raise DataError(f"time series: weights must be (rows, k) = ({n}, k), got shape {w.shape}")
        starts, means = bucket_means(w, segment, factor)
        for j in range(means.shape[1]):
            xs, ys = gapped(x[starts], means[:, j], segment[starts])
            fig.add_trace(go.Scatter(x=_f32(xs), y=_f32(ys), mode="lines", stackgroup="weights", name=f"expert {j + 1}",
                                     legendgroup="weights", line={"width": 0.5, "color": PALETTE[(j + 3) % len(PALETTE)]},
                                     legendgrouptitle_text=f"weights: {weights_label}" if j == 0 else None,
                                     legendrank=2000 + j),  # after every method (1000 + k) in the legend
                          row=2, col=1)
        fig.update_yaxes(title_text=f"{weights_label} weights [-]" if weights_label else "weights [-]", range=[0, 1],
                         row=2, col=1)
        fig.update_xaxes(title_text=x_label, row=2, col=1)
        fig.update_yaxes(title_text=y_label, row=1, col=1)
    else:
        fig.update_xaxes(title_text=x_label)
        fig.update_yaxes(title_text=y_label)
    fig.update_layout(title=_title(title, subtitle), height=620 if rows_panel == 2 else 460,
                      margin={"l": 70, "r": 20, "t": 80, "b": 50}, hovermode="x unified",
                      legend={"orientation": "h", "y": -0.14 if rows_panel == 1 else -0.1, "x": 0})
    return fig


def scatter_figure(
    measured: np.ndarray,
    predicted: Mapping[str, np.ndarray],
    *,
    title: str = "",
    label: str = "y",
    max_points: int = MAX_POINTS,
):
    """Measured (x) vs predicted (y), one trace per method, with the identity line; evenly thinned beyond ``max_points``."""
    go = _go()
    t = np.asarray(measured, dtype=float)
    n = t.size
    if n == 0:
        raise DataError("scatter: no points")
    rows = np.arange(n) if n <= max_points else np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))
    fig = go.Figure()
    finite = [t[np.isfinite(t)]]
    kind = _scatter_type(go, len(rows))
    for k, (name, values) in enumerate(predicted.items()):
        p = np.asarray(values, dtype=float)
        if p.shape != t.shape:
            raise DataError(f"scatter: {name!r} has shape {p.shape}; expected {t.shape} like the measured values")
        finite.append(p[np.isfinite(p)])
        fig.add_trace(kind(x=_f32(t[rows]), y=_f32(p[rows]), mode="markers", name=name, opacity=0.55,
                                 marker={"size": 4, "color": PALETTE[k % len(PALETTE)]}))
    both = np.concatenate(finite)
    lo, hi = (float(both.min()), float(both.max())) if both.size else (0.0, 1.0)
    pad = 0.03 * (hi - lo) if hi > lo else 1.0
    fig.add_trace(kind(x=[lo, hi], y=[lo, hi], mode="lines", name="identity", line={"color": "black", "width": 1}))
    subtitle = f"{len(rows)} of {n} rows (evenly spaced)" if len(rows) < n else f"{n} rows"
    fig.update_layout(title=_title(title, subtitle), height=560, width=640, margin={"l": 70, "r": 20, "t": 80, "b": 50},
                      xaxis={"title": f"measured {label}", "range": [lo - pad, hi + pad], "constrain": "domain"},
                      yaxis={"title": f"predicted {label}", "range": [lo - pad, hi + pad], "scaleanchor": "x",
                             "scaleratio": 1, "constrain": "domain"},
                      legend={"orientation": "h", "y": -0.15, "x": 0})
    return fig


def operating_map_figure(m, *, title: str = "", unit: str = "", axis_units: Mapping[str, str] | None = None):
    """Heat maps of an ``operating_map.OperatingMap``: the training rows per bin, then each method's RMSE per bin
    (one shared colour scale); bins with evaluated rows but no training row are marked x (extrapolation).
    ``axis_units`` (column -> unit) labels the two inputs' axes ``name [unit]``."""
    from plotly.subplots import make_subplots

    from enginebench.results.units import axis_label

    go = _go()
    methods = list(m.rmse)
    panels = ["training rows"] + [f"{k}: RMSE" for k in methods]
    cols = min(3, len(panels))
    nrows = math.ceil(len(panels) / cols)
    fig = make_subplots(rows=nrows, cols=cols, subplot_titles=panels, horizontal_spacing=0.08, vertical_spacing=0.14)
    xc, yc = 0.5 * (m.x_edges[1:] + m.x_edges[:-1]), 0.5 * (m.y_edges[1:] + m.y_edges[:-1])
    finite = np.concatenate([v[np.isfinite(v)] for v in m.rmse.values()]) if methods else np.empty(0)
    top = float(finite.max()) if finite.size else 1.0
    ey, ex = np.nonzero(m.extrapolated)
    for k, name in enumerate(panels):
        r, c = k // cols + 1, k % cols + 1
        if k == 0:
            z, scale, zmax, bar = np.where(m.train_rows > 0, m.train_rows, np.nan), "Greys", None, None
            hover = "training rows %{z}<extra></extra>"
        else:
            z, scale, zmax = m.rmse[methods[k - 1]], "Viridis", top
            bar = {"title": f"RMSE{f' [{unit}]' if unit else ''}", "len": 0.8} if k == 1 else None
            hover = "RMSE %{z:.4g}<extra></extra>"
        fig.add_trace(go.Heatmap(x=xc, y=yc, z=z, colorscale=scale, zmin=0, zmax=zmax, showscale=bar is not None,
                                 colorbar=bar, hovertemplate=f"{m.x_name} %{{x:.3g}}, {m.y_name} %{{y:.3g}}<br>{hover}"),
                      row=r, col=c)
        if len(ex):
            fig.add_trace(go.Scatter(x=xc[ex], y=yc[ey], mode="markers", marker={"symbol": "x", "color": "red", "size": 9},
                                     name="no training rows", showlegend=k == 0, hoverinfo="skip"), row=r, col=c)
        fig.update_xaxes(title_text=axis_label(m.x_name, (axis_units or {}).get(m.x_name)), row=r, col=c)
        fig.update_yaxes(title_text=axis_label(m.y_name, (axis_units or {}).get(m.y_name)), row=r, col=c)
    fig.update_layout(title=_title(title, "bins over the range of the training and evaluated rows; x: evaluated "
                                          "rows but no training row (extrapolation)"),
                      height=320 * nrows + 120, margin={"l": 60, "r": 20, "t": 110, "b": 50},
                      legend={"orientation": "h", "y": -0.08, "x": 0})
    return fig


def importance_figure(importance: Mapping[str, Mapping[str, float]], *, title: str = "", unit: str = ""):
    """Horizontal bars: per method, how much the error grows when each input is shuffled (``describe``'s
    ``importance``)."""
    go = _go()
    fig = go.Figure()
    for k, (method, values) in enumerate(importance.items()):
        names = list(values)[::-1]
        fig.add_trace(go.Bar(x=[values[n] for n in names], y=names, orientation="h", name=method,
                             marker={"color": PALETTE[k % len(PALETTE)]}))
    fig.update_layout(title=_title(title), barmode="group", height=140 + 40 * max(len(v) for v in importance.values()),
                      margin={"l": 110, "r": 20, "t": 70, "b": 50},
                      xaxis_title=f"RMSE increase when shuffled{f' [{unit}]' if unit else ''}")
    return fig


def strip_figure(rows: pd.DataFrame, *, title: str = "", y_label: str = "value"):
    """One point per repetition per method (columns method, repetition, value; optional ``block``, one trace each)."""
    go = _go()
    missing = {"method", "repetition", "value"} - set(rows.columns)
    if missing:
        raise DataError(f"strip plot: the rows lack column(s) {', '.join(sorted(missing))}")
    blocks = rows.groupby("block", sort=False) if "block" in rows and rows["block"].nunique() > 1 else [("", rows)]
    fig = go.Figure()
    for k, (block, part) in enumerate(blocks):
        fig.add_trace(go.Box(
            x=part["method"].astype(str), y=part["value"].astype(float), name=str(block) or "repetitions",
            boxpoints="all", jitter=0.5, pointpos=0, fillcolor="rgba(0,0,0,0)", line={"color": "rgba(0,0,0,0)"},
            marker={"size": 7, "color": PALETTE[k % len(PALETTE)]}, hoveron="points",
            customdata=part["repetition"].astype(int), showlegend=bool(block),
            hovertemplate="%{x}<br>repetition %{customdata}: %{y:.4g}<extra></extra>"))
    fig.update_layout(title=_title(title), height=360, margin={"l": 70, "r": 20, "t": 60, "b": 60},
                      yaxis_title=y_label, boxmode="group" if len(fig.data) > 1 else "overlay")
    return fig


def validation_figure(selection: pd.DataFrame, *, title: str = "", unit: str = ""):
    """Validation score against the searched hyperparameter of one (target, window, split, method), or None.

    ``selection`` has ``Run.selection_table()``'s columns (``param:<name>``..., repetition,
    point, resample, score, criterion, chosen). The x axis is the parameter with the most
    values (log scale when positive over at least a decade); each combination of the
    others is one line of the mean score over repetitions and resamples; each
    repetition's chosen point is a star. None when the search had a single point. ``unit``: the
    score's unit (the target's for one target; a joint job's scores are standardised, ``-``).
    """
    go = _go()
    params = [c for c in selection.columns if str(c).startswith(PARAM_PREFIX)]
    varied = [c for c in params if selection[c].nunique(dropna=False) > 1]
    if not varied or selection.empty:
        return None
    xcol = max(varied, key=lambda c: selection[c].nunique())
    others = [c for c in varied if c != xcol]
    per_rep = selection.groupby(["repetition", "point"] + varied, sort=False, dropna=False).agg(
        score=("score", "mean"), chosen=("chosen", "any")).reset_index()
    fig = go.Figure()
    groups = per_rep.groupby(others, sort=True, dropna=False) if others else [((), per_rep)]
    for k, (key, part) in enumerate(groups):
        key = key if isinstance(key, tuple) else (key,)
        name = ", ".join(f"{c[len(PARAM_PREFIX):]}={v:.3g}" if isinstance(v, (float, np.floating)) else
                         f"{c[len(PARAM_PREFIX):]}={v}" for c, v in zip(others, key)) or "mean score"
        curve = part.groupby(xcol, sort=True)["score"].mean()
        fig.add_trace(go.Scatter(x=curve.index.to_numpy(), y=curve.to_numpy(), mode="lines+markers", name=name,
                                 line={"color": PALETTE[k % len(PALETTE)]}, legendgroup=name))
    chosen = per_rep[per_rep["chosen"]]
    if not chosen.empty:
        fig.add_trace(go.Scatter(x=chosen[xcol], y=chosen["score"], mode="markers", name="chosen (per repetition)",
                                 marker={"symbol": "star", "size": 12, "color": "black"},
                                 customdata=chosen["repetition"],
                                 hovertemplate="repetition %{customdata}: %{y:.4g}<extra>chosen</extra>"))
    xs = pd.to_numeric(selection[xcol], errors="coerce").to_numpy(dtype=float)
    log = bool(np.isfinite(xs).all() and (xs > 0).all() and xs.max() / xs.min() >= 10)
    criterion = str(selection["criterion"].iloc[0]) if "criterion" in selection else "score"
    fig.update_layout(title=_title(title), height=400, margin={"l": 70, "r": 20, "t": 60, "b": 50},
                      xaxis={"title": xcol[len(PARAM_PREFIX):], "type": "log" if log else "linear"},
                      yaxis_title=f"validation {criterion}" + (f" [{unit}]" if unit else ""))
    return fig


# -- HTML -----------------------------------------------------------------------------

def plotly_script() -> str:
    """plotly.js inlined as one ``<script>`` (no network reference), to precede every figure of the page."""
    from plotly.offline import get_plotlyjs

    return f"<script type=\"text/javascript\">{get_plotlyjs()}</script>\n"


def figure_html(fig, div_id: str) -> str:
    """A figure's ``<div>`` and its drawing script, without plotly.js (``plotly_script`` carries it once)."""
    return fig.to_html(full_html=False, include_plotlyjs=False, include_mathjax=False, div_id=div_id,
                       config=PLOT_CONFIG)


SORT_SCRIPT = """<script type="text/javascript">
document.querySelectorAll("table.sortable").forEach(function (table) {
  table.querySelectorAll("thead th").forEach(function (th, col) {
    th.addEventListener("click", function () {
      var body = table.tBodies[0], rows = Array.from(body.rows);
      var up = th.getAttribute("data-order") !== "asc";
      var key = function (r) { var s = r.cells[col].textContent.trim(), v = parseFloat(s); return isNaN(v) ? s : v; };
      rows.sort(function (a, b) {
        var x = key(a), y = key(b), kx = typeof x, ky = typeof y;
        if (kx !== ky) return kx === "number" ? -1 : 1;  // text ("n/a") after the numbers either way
        var c = x < y ? -1 : x > y ? 1 : 0;
        return up ? c : -c;
      });
      rows.forEach(function (r) { body.appendChild(r); });
      table.querySelectorAll("thead th").forEach(function (h) { h.removeAttribute("data-order"); });
      th.setAttribute("data-order", up ? "asc" : "desc");
    });
  });
});
</script>
"""
"""Click a header to sort a ``table.sortable`` by that column (numbers by value, ascending then descending; text last)."""


def sortable_table(headers: Sequence[str], rows: Sequence[Sequence[str]], bold: Sequence[Sequence[bool]] | None = None,
                   ) -> str:
    """An escaped ``<table class="sortable">`` (``SORT_SCRIPT`` makes its headers sort on click); ``bold`` marks cells."""
    head = "".join(f"<th title=\"click to sort\">{html.escape(str(h))}</th>" for h in headers)
    body = []
    for i, row in enumerate(rows):
        if len(row) != len(headers):
            raise DataError(f"table: row {i} has {len(row)} cells but there are {len(headers)} headers")
        flags = bold[i] if bold is not None else [False] * len(row)
        body.append("<tr>" + "".join(f"<td><b>{html.escape(str(c))}</b></td>" if f else f"<td>{html.escape(str(c))}</td>"
                                     for c, f in zip(row, flags)) + "</tr>")
    return (f"<table class=\"sortable\">\n<thead><tr>{head}</tr></thead>\n<tbody>\n" + "\n".join(body)
            + "\n</tbody>\n</table>\n")


def figure_json(fig) -> dict:
    """The figure as plain JSON data (what the page embeds), for checks."""
    return json.loads(fig.to_json())
