"""One self-contained interactive HTML file of a stored run (plotly, JavaScript inlined once).

``write_interactive_report(run, PATH)`` writes a page that opens offline: the comparison
table sortable by clicking its headers, failed jobs with their reasons, zoomable time
series of the evaluated part (one toggleable trace per method, diverged trajectories
dashed, mixing weights as stacked bands underneath), measured vs predicted scatters,
each metric per repetition, and the validation curves of model selection. The
predictions come from the same re-fit as the static report (``refit.refit_predictions``
for static/window runs, ``trajectories.simulate_run`` for simulation runs); ``write_reports``
writes both pages from one re-fit. Figures are built by ``reports.interactive_figures``.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from enginebench.errors import EngineBenchError
from enginebench.reports.refit import Predictions, refit_predictions
from enginebench.reports.static import (
    REPORT_FILE, ReportResult, ReportSettings, _synthetic, is_learning_curve, run_verdicts, verdict_html, write_report,
)
from enginebench.reports.static_figures import _time_axis
from enginebench.results import tables
from enginebench.results.notes import run_note_lines
from enginebench.results.run_folder import Run

INTERACTIVE_FILE = "report.html"
INSTALL_HINT = 'pip install "enginebench[report]"'


def plotly_available() -> bool:
    """True when plotly (the optional extra ``report``) can be imported."""
    try:
        import plotly  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass
class InteractiveResult:
    """What ``write_interactive_report`` wrote: the file, its figures' titles and the notes shown in it."""

    path: Path
    figures: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def run_units(run: Run) -> dict[str, str]:
    """Column -> unit as the run recorded them (``{}`` for a run made before units were recorded)."""
    from enginebench.results.units import run_units as recorded

    return recorded(run.info())


@dataclass
class _Page:
    """The figures and fragments of the page, in order."""

    sections: list[tuple[str, str, list[str]]] = field(default_factory=list)
    titles: list[str] = field(default_factory=list)

    def figure(self, fig, caption: str) -> str:
        from enginebench.reports.interactive_figures import figure_html

        self.titles.append(caption)
        return (f"<figure>{figure_html(fig, f'figure-{len(self.titles)}')}"
                f"<figcaption>{html.escape(caption)}</figcaption></figure>\n")

    def add(self, anchor: str, title: str, fragments: list[str]) -> None:
        if fragments:
            self.sections.append((anchor, title, fragments))


def _series(predictions: Sequence[Predictions], simulated: Sequence[Any]) -> list[dict[str, Any]]:
    """The re-fitted series, one dict per (target, window, split): rows shared by every method."""
    groups: dict[tuple, list[Predictions]] = {}
    for p in predictions:
        groups.setdefault((p.target, p.window, p.split, p.part), []).append(p)
    out = []
    for (target, window, split, part), group in groups.items():
        first = group[0]
        weighed = next((p for p in group if p.weights is not None), None)
        out.append({"target": target, "window": window, "split": split, "part": part, "repetition": first.repetition,
                    "time": first.time, "segment": first.segment, "truth": first.truth,
                    "pred": {p.method: p.pred for p in group}, "diverged": {p.method: p.diverged for p in group},
                    "weights": None if weighed is None else weighed.weights,
                    "weights_label": "" if weighed is None else weighed.method, "what": "re-fitted"})
    for sim in simulated:
        lengths = [len(t) for t in sim.time]
        segment = np.repeat(np.arange(len(lengths)), lengths)
        out.append({"target": sim.target, "window": sim.window, "split": sim.split, "part": sim.part,
                    "mode": "simulation",
                    "repetition": sim.repetition, "time": np.concatenate(sim.time), "segment": segment,
                    "truth": np.concatenate(sim.truth), "pred": {m: np.concatenate(v) for m, v in sim.sims.items()},
                    "diverged": {m: np.repeat(f, lengths) for m, f in sim.diverged.items()},
                    "weights": None if sim.gate is None else np.concatenate(sim.gate), "weights_label": sim.gate_label,
                    "what": f"re-fitted, simulated; trajectories {', '.join(sim.segment_ids)}"})
    return out


def end_to_end(seconds: np.ndarray, segment: np.ndarray) -> tuple[np.ndarray, bool]:
    """Times laid end to end where segments overlap in time (two engines of one flight, records restarting at 0),
    so that no trajectory is drawn over another: each segment starts one median sample period after the previous
    one ended, in order of appearance. Returns the times and whether they were moved."""
    seconds = np.asarray(seconds, dtype=float)
    segment = np.asarray(segment)
    if seconds.size == 0:
        return seconds, False
    order = list(dict.fromkeys(segment.tolist()))
    spans = [(seconds[segment == g].min(), seconds[segment == g].max()) for g in order]
    if all(b_start > a_end for (_, a_end), (b_start, _) in zip(spans, spans[1:])):
        return seconds, False
    steps = np.diff(seconds)
    gap = float(np.median(steps[steps > 0])) if (steps > 0).any() else 1.0
    out = np.empty_like(seconds)
    cursor = 0.0
    for g, (start, end) in zip(order, spans):
        rows = segment == g
        out[rows] = seconds[rows] - start + cursor
        cursor += end - start + gap
    return out, True


def _prediction_sections(page: _Page, series: list[dict[str, Any]], units: dict[str, str], max_points: int) -> None:
    from enginebench.reports.interactive_figures import scatter_figure, time_series_figure
    from enginebench.results.units import axis_label

    trends, scatters = [], []
    for s in series:
        seconds, moved = end_to_end(s["time"], s["segment"])
        x, tunit = _time_axis(seconds)
        x_label = (f"time, {s['part']} segments end to end ({tunit})" if moved
                   else f"time since the first shown {s['part']} row ({tunit})")
        where = (f"{s['target']}, split {s['split']}" if s.get("mode") == "simulation"
                 else f"{s['target']}, window {s['window']:g} s, split {s['split']}")
        about = f"{s['part']} part, repetition {s['repetition']} ({s['what']})"
        label = axis_label(s["target"], units.get(s["target"]))
        n_div = {m: int(np.count_nonzero(np.diff(np.r_[0, d.astype(int)]) == 1))
                 for m, d in s["diverged"].items() if d is not None and d.any()}
        caption = f"{where}: measured and predicted over time on the {about}" + (
            "; diverged (dashed): " + ", ".join(f"{m} ({k} segment{'s' * (k != 1)})" for m, k in n_div.items())
            if n_div else "") + (f"; {s['weights_label']} mixing weights as bands underneath" if s["weights_label"]
                                 else "")
        trends.append(page.figure(time_series_figure(
            x, s["segment"], s["truth"], s["pred"], diverged=s["diverged"], weights=s["weights"],
            weights_label=s["weights_label"], title=f"{where}: {s['part']} part", y_label=label,
            x_label=x_label, max_points=max_points), caption))
        scatters.append(page.figure(scatter_figure(s["truth"], s["pred"], title=f"{where}: measured vs predicted",
                                                   label=label, max_points=max_points),
                                    f"{where}: measured vs predicted on the {about}"))
    page.add("series", "Time series", trends)
    page.add("scatter", "Measured vs predicted", ["<div class=\"grid\">\n" + "".join(scatters) + "</div>\n"]
             if scatters else [])


def _importance_section(page: _Page, run: Run, units: dict[str, str]) -> None:
    """Input importances of the methods whose ``describe`` gives ``importance.targets[T].by_input`` (first repetition)."""
    from enginebench.reports.interactive_figures import importance_figure

    found: dict[str, dict[str, dict[str, float]]] = {}
    for meta in run.job_metas().values():
        targets = ((meta.get("describe") or {}).get("importance") or {}).get("targets") or {}
        if meta.get("status") != "ok" or meta.get("repetition", 0) != 0:
            continue
        for target, imp in targets.items():
            if isinstance(imp, dict) and isinstance(imp.get("by_input"), dict):
                found.setdefault(target, {})[str(meta.get("method"))] = imp["by_input"]
    figures = [page.figure(importance_figure(v, title=f"{t}: input importance", unit=units.get(t, "")),
                           f"{t}: how much each method's training RMSE grows when one input's whole history is "
                           "shuffled across rows (permutation importance, repetition 0)")
               for t, v in sorted(found.items())]
    page.add("importance", "Input importance", figures)


def _map_section(page: _Page, simulated: Sequence[Any], units: dict[str, str]) -> None:
    """Each simulated target's free-run RMSE over the operating map of the first two run-time inputs."""
    from enginebench.reports.interactive_figures import operating_map_figure
    from enginebench.reports.operating_map import operating_map

    figures = []
    for sim in simulated:
        names = list(sim.train_inputs)
        if len(names) < 2 or not sim.sims:
            continue
        x, y = (np.concatenate([seg[n] for seg in sim.inputs]) for n in names[:2])
        m = operating_map(x, y, np.concatenate(sim.truth), {k: np.concatenate(v) for k, v in sim.sims.items()},
                          sim.train_inputs[names[0]], sim.train_inputs[names[1]], names=(names[0], names[1]))
        where = f"{sim.target}, split {sim.split}"
        figures.append(page.figure(
            operating_map_figure(m, title=f"{where}: free-run error over {names[0]} x {names[1]}",
                                 unit=units.get(sim.target, ""), axis_units=units),
            f"{where}: RMSE per bin of {names[0]} x {names[1]} on the simulated {sim.part} records "
            f"({', '.join(sim.segment_ids)}), beside where the training rows lie"))
    page.add("map", "Error over the operating map", figures)


def _table_section(page: _Page, summary: pd.DataFrame, metrics: Sequence[str], units: dict[str, str]) -> None:
    from enginebench.reports.interactive_figures import sortable_table
    from enginebench.results.units import header
    from enginebench.results.units import window_header

    cells, bold = tables.wide(summary, metrics)
    targets = set(summary["target"].astype(str))
    unit = units.get(next(iter(targets))) if len({units.get(t) for t in targets}) == 1 else None
    heads = [window_header() if n == "window" else n for n in cells.index.names] + [header(c, unit) if c in set(summary["metric"]) else c for c in cells.columns]
    rows = []
    for idx, row in cells.iterrows():
        idx = idx if isinstance(idx, tuple) else (idx,)
        rows.append([f"{k:g}" if isinstance(k, float) else str(k) for k in idx] + [str(v) for v in row])
    flags = [[False] * len(cells.index.names) + [bool(b) for b in r] for r in bold.to_numpy()]
    notes = "".join(f"<p class=\"note\">{html.escape(n)}</p>\n" for n in tables.table_notes(summary, cells))
    page.add("table", "Comparison table", ["<p>Click a header to sort by it.</p>\n" + sortable_table(heads, rows, flags)
                                           + notes])


def _strip_section(page: _Page, raw: pd.DataFrame, metrics: Sequence[str], units: dict[str, str]) -> None:
    from enginebench.reports.interactive_figures import strip_figure
    from enginebench.results.units import header

    ok = raw[raw["status"] == "ok"] if "status" in raw else raw
    ok = ok.assign(block=[f"{t}, window {w:g} s, {s}" for t, w, s in zip(ok["target"], ok["window"], ok["split"])])
    targets = set(ok["target"].astype(str))
    unit = units.get(next(iter(targets))) if targets and len({units.get(t) for t in targets}) == 1 else None
    figs = []
    for metric in metrics:
        rows = ok[ok["metric"] == metric]
        if rows.empty:
            continue
        title = f"{metric} per repetition"
        figs.append(page.figure(strip_figure(rows, title=title, y_label=header(metric, unit)),
                                f"{metric} of each repetition (one point each; hover for its number)"))
    page.add("repetitions", "Metrics per repetition", ["<div class=\"grid\">\n" + "".join(figs) + "</div>\n"]
             if figs else [])


def _validation_section(page: _Page, run: Run, units: dict[str, str] | None = None) -> str | None:
    """Validation curves from ``Run.selection_table()``; a note instead where the run has none."""
    from enginebench.reports.interactive_figures import validation_figure

    if not hasattr(run, "selection_table"):
        return "validation curves: this version of the run store does not read model-selection scores"
    table = run.selection_table()
    if table is None or table.empty:
        return "validation curves: the run stored no model-selection scores (no search, or an older run)"
    figs = []
    for (target, window, split, method), part in table.groupby(["target", "window", "split", "method"], sort=False):
        where = f"{method}: {target}, window {float(window):g} s, split {split}"
        fig = validation_figure(part, title=where, unit=_score_unit(str(target), units or {}, part))
        if fig is not None:
            figs.append(page.figure(fig, f"{where}: validation score over the searched grid (mean over repetitions "
                                         "and resamples; stars: the point each repetition chose)"))
    page.add("validation", "Validation curves", figs)
    return None if figs else "validation curves: every search had a single point"


def _score_unit(target: str, units: dict[str, str], selection: pd.DataFrame) -> str:
    """The unit of one target's validation scores (mae, rmse and rmae are in the target's unit); '' when unknown."""
    from enginebench.results.metrics import CRITERIA

    criteria = set(selection["criterion"].astype(str)) if "criterion" in selection else set()
    return units.get(target, "") if criteria and criteria <= set(CRITERIA) else ""


_STYLE = """
body { font-family: sans-serif; margin: 1.5em 2em; max-width: 1300px; color: #222; }
nav a { margin-right: 1em; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: right; }
th { background: #f2f2f2; cursor: pointer; user-select: none; }
th[data-order=asc]::after { content: " \\25B2"; } th[data-order=desc]::after { content: " \\25BC"; }
figure { margin: 0.8em 0 1.6em 0; min-width: 0; }
.grid { display: grid; grid-template-columns: repeat(auto-fill, minmax(560px, 1fr)); gap: 0 1.5em; } figcaption { color: #444; font-size: 0.9em; }
pre { background: #f7f7f7; padding: 0.6em; overflow-x: auto; font-size: 0.85em; }
.synthetic { color: #a00; font-weight: bold; } .note { color: #555; } .failed { color: #a00; }
ul.verdict li { font-size: 1.05em; margin: 0.2em 0; }
"""


def _html(run: Run, page: _Page, failures: list[str], notes: list[str], verdict: str = "") -> str:
    from enginebench.reports.interactive_figures import SORT_SCRIPT, plotly_script

    cfg, info = run.config(), run.info()
    esc = html.escape
    out = [f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
           f"<title>enginebench interactive report: {esc(run.id)}</title>\n<style>{_STYLE}</style>\n"
           f"{plotly_script()}</head>\n<body>\n<h1>Run {esc(run.id)}</h1>\n{verdict}"
           f"<p>experiment <b>{esc(str(cfg.get('name', '?')))}</b> on dataset <b>{esc(str(cfg.get('dataset', '?')))}</b>;"
           f" targets {esc(', '.join(map(str, cfg.get('targets', []))))}; mode {esc(str(cfg.get('mode', '?')))}; "
           f"{esc(str(cfg.get('repetitions', '?')))} repetitions, seed {esc(str(cfg.get('seed', '?')))}; status "
           f"{esc(str(info.get('status', '?')))}, {esc(str(info.get('failed_jobs', 0)))} of "
           f"{esc(str(info.get('n_jobs', '?')))} jobs failed. Static version: <a href=\"{REPORT_FILE}\">{REPORT_FILE}</a>"
           "</p>\n"]
    if _synthetic(cfg.get("dataset", "")):
        out.append("<p class=\"synthetic\">SYNTHETIC data (generated by enginebench): not measurements of a real "
                   "engine.</p>\n")
    sections = list(page.sections)
    where = 1 if sections and sections[0][0] == "table" else 0
    sections.insert(where, ("failures", "Failed jobs and warnings",
                            ["<ul>\n" + "".join(f"<li class=\"{'failed' if f.startswith('failed') else 'note'}\">"
                                                f"{esc(f)}</li>\n" for f in failures) + "</ul>\n"]
                            if failures else ["<p class=\"note\">no job failed or warned</p>\n"]))
    if notes:
        sections.append(("notes", "Notes", ["<ul>\n" + "".join(f"<li class=\"note\">{esc(n)}</li>\n" for n in notes)
                                            + "</ul>\n"]))
    cfg_text = (run.path / "config.toml").read_text() if (run.path / "config.toml").is_file() else ""
    sections.append(("settings", "Config and run info", [f"<pre>{esc(cfg_text)}</pre>\n<pre>"
                                                         f"{esc(json.dumps(info, indent=2))}</pre>\n"]))
    out.append("<nav>" + "".join(f"<a href=\"#{a}\">{esc(t)}</a>" for a, t, _ in sections) + "</nav>\n")
    for anchor, title, fragments in sections:
        out.append(f"<h2 id=\"{anchor}\">{esc(title)}</h2>\n" + "".join(fragments))
    out.append(SORT_SCRIPT + "</body>\n</html>\n")
    return "".join(out)


def write_interactive_report(
    run: Run,
    path: str | Path,
    *,
    max_points: int | None = None,
    predictions: Sequence[Predictions] | None = None,
    simulated: Sequence[Any] | None = None,
    notes: Sequence[str] = (),
    **settings: Any,
) -> InteractiveResult:
    """Write the interactive page of ``run`` to ``path`` (one HTML file, plotly.js inlined once).

    ``settings``: the keywords of ``report.ReportSettings`` (metrics, interval, figures,
    repetition, part, methods, trajectories), as for ``write_report``.
    The time series and scatters come from ``predictions`` / ``simulated`` when given
    (what ``write_report`` re-fitted), otherwise from re-fitting ``repetition`` here;
    ``figures=False`` draws none of them (no data loaded). ``notes`` are shown on the page.
    """
    opts = ReportSettings(**settings)
    repetition, part, methods = opts.repetition, opts.part, opts.methods
    from enginebench.reports.interactive_figures import MAX_POINTS

    max_points = MAX_POINTS if max_points is None else max_points
    cfg = run.config()
    raw = run.metrics()
    summary = tables.summarize(raw, interval=opts.interval or cfg.get("interval", "t"))
    metrics = list(opts.metrics) if opts.metrics else list(tables.default_metrics(summary))
    units = run_units(run)
    result = InteractiveResult(Path(path), notes=list(notes))
    page = _Page()
    _table_section(page, summary, metrics, units)
    if opts.figures and not is_learning_curve(run):
        if predictions is None and simulated is None:
            try:
                if cfg.get("mode") == "simulation":
                    from enginebench.reports.trajectories import simulate_run

                    simulated, more = simulate_run(run, list(methods) if methods else None, opts.trajectories, part,
                                                   repetition)
                else:
                    predictions, more = refit_predictions(run, repetition=repetition, part=part, methods=methods)
                result.notes += more
            except EngineBenchError as exc:
                if methods:
                    raise
                result.notes.append(f"prediction figures skipped: {exc}")
        _prediction_sections(page, _series(predictions or [], simulated or []), units, max_points)
        _map_section(page, simulated or [], units)
    elif opts.figures:
        result.notes.append("learning-curve run: no prediction figures (each amount of data is its own model); "
                            f"its curve is in {REPORT_FILE}")
    _importance_section(page, run, units)
    _strip_section(page, raw, metrics, units)
    missing = _validation_section(page, run, units)
    if missing:
        result.notes.append(missing)
    result.figures = list(page.titles)
    result.path.parent.mkdir(parents=True, exist_ok=True)
    metric = tables.default_paired_metric(str(cfg.get("mode", "")))
    verdict = verdict_html(run_verdicts(run, raw, summary, tables.paired_tests(raw, metric), metric))
    result.path.write_text(_html(run, page, run_note_lines(run), result.notes, verdict), encoding="utf-8")
    return result


def write_reports(run: Run, out_dir: str | Path, *, interactive: bool = True, **options: Any
                  ) -> tuple[ReportResult, InteractiveResult | None, list[str]]:
    """``DIR/index.html`` (``write_report``) and, with plotly installed, ``DIR/report.html`` from the same re-fit.

    Returns both results and the notes for the user (the static report's, plus how to get
    the interactive one when plotly is missing).
    """
    make = interactive and plotly_available()
    static = write_report(run, out_dir, interactive=INTERACTIVE_FILE if make else None, **options)
    notes = list(static.notes)
    if interactive and not make:
        notes.append(f"interactive report ({INTERACTIVE_FILE}) not written: plotly is not installed; {INSTALL_HINT}")
    if not make:
        return static, None, notes
    keep = {k: options[k] for k in ReportSettings.names() if k in options}
    page = write_interactive_report(run, Path(out_dir) / INTERACTIVE_FILE, predictions=static.predictions,
                                    simulated=static.simulated, notes=static.notes, **keep)
    notes += [n for n in page.notes if n not in static.notes]
    return static, page, notes
