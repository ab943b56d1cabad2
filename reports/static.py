"""An HTML report of a stored run: its tables, its settings and PNG figures, in one folder.

``write_report(run, DIR)`` writes ``DIR/index.html`` and, beside it, the comparison table
as csv and the figures as PNG files referenced by relative names, so the folder can be
copied, zipped or logged as one artefact:

- the comparison table (``results.tables``), the paired tests of every method against
  its block's best, and the run's info, config and environment;
- measured vs predicted scatters and time trends of the evaluated part (test by
  default). Predictions are not stored in a run, so they come from re-fitting one
  repetition: a simulation run is redrawn by ``reports.trajectories.plot_run``
  (trajectories, with gate bands underneath from the first method whose ``explain``
  hook declares mixing weights, e.g. a mixture of experts); in
  static and window modes each method is fitted again on that repetition's training
  subsample with the hyperparameters the run selected (``refit_predictions``);
- the learning curve, for a run made by ``enginebench learning-curve``.

A figure that cannot be drawn (a missing dataset, a failed re-fit) is skipped with a
note in the page, never silently.

This module writes the page; the re-fit is ``refit.py`` and the PNG figures
``static_figures.py``.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from enginebench.errors import EngineBenchError, MethodError
from enginebench.reports.refit import MAX_ROWS, REFIT_ERRORS, Predictions, refit_predictions
from enginebench.reports.static_figures import Figure, prediction_figures, simulation_figures, time_trend_plot
from enginebench.results import tables
from enginebench.results.notes import run_note_lines
from enginebench.results.run_folder import Run
from enginebench.results.units import run_units
from enginebench.results.verdict import Verdict, verdicts

__all__ = [
    "Figure",
    "MAX_ROWS",
    "Predictions",
    "REFIT_ERRORS",
    "REPORT_FILE",
    "ReportResult",
    "ReportSettings",
    "TABLE_FILE",
    "run_verdicts",
    "verdict_html",
    "is_learning_curve",
    "refit_predictions",
    "time_trend_plot",
    "write_report",
]

REPORT_FILE = "index.html"
TABLE_FILE = "table.csv"


@dataclass
class ReportResult:
    """What ``write_report`` wrote: the page, its figures, and the notes shown in it."""

    index: Path
    table: Path
    figures: list[Figure] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    predictions: list[Predictions] = field(default_factory=list)
    simulated: list = field(default_factory=list)
    """Simulation runs: the re-fitted trajectories drawn (``trajectories.Simulated``)."""


@dataclass(frozen=True)
class ReportSettings:
    """What a report shows and re-fits: the keywords ``write_report`` and ``write_interactive_report`` share.

    ``metrics``: the table's columns (default: those of the run's mode); ``interval``: of
    the summary (default: the run's); ``figures=False``: tables only; ``repetition``,
    ``part`` and ``methods``: what is re-fitted and predicted for the figures (default: all
    methods); ``trajectories``: segments drawn per method of a simulation run.
    """

    metrics: Sequence[str] | None = None
    interval: str | None = None
    figures: bool = True
    repetition: int = 0
    part: str = "test"
    methods: Sequence[str] | None = None
    trajectories: int = 3

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


def is_learning_curve(run: Run) -> bool:
    """True for a run written by ``enginebench learning-curve`` (its config carries the curve settings)."""
    return "learning_curve" in run.config()


# -- the page -----------------------------------------------------------------------

_STYLE = """
body { font-family: sans-serif; margin: 2em; max-width: 1200px; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: right; }
th { background: #f2f2f2; }
pre { background: #f7f7f7; padding: 0.6em; overflow-x: auto; font-size: 0.85em; }
figure { display: inline-block; margin: 0.5em; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #ddd; }
.synthetic { color: #a00; font-weight: bold; }
.note { color: #555; }
ul.verdict li { font-size: 1.05em; margin: 0.2em 0; }
"""


def run_verdicts(run: Run, raw: pd.DataFrame, summary: pd.DataFrame, paired: pd.DataFrame | None,
                 metric: str | None = None) -> list[Verdict]:
    """The verdict per test block of ``run`` (``results.verdict``), on ``metric`` (default: the paired tests' metric)."""
    metric = metric or tables.default_paired_metric(str(run.config().get("mode", "")))
    return verdicts(raw, summary, paired, metric, run.job_metas().values())


def verdict_html(found: Sequence[Verdict]) -> str:
    """The verdict section a report opens on: one list item per block (a note where there is none)."""
    if not found:
        return ("<section id=\"verdict\">\n<h2>Verdict</h2>\n<p class=\"note\">no verdict: no block scored on its "
                "test part</p>\n</section>\n")
    items = "".join(f"<li>{html.escape(v.text())}</li>\n" for v in found)
    return (f"<section id=\"verdict\">\n<h2>Verdict</h2>\n<ul class=\"verdict\">\n{items}</ul>\n"
            f"<p class=\"note\">per target: the lowest mean {html.escape(found[0].metric)} on the test part; its margin "
            "over the best baseline (family baseline: training mean, linear, naive) with the paired t-test over "
            "repetitions, Holm-adjusted over the tests listed under the table</p>\n</section>\n")


def _frame_html(frame: pd.DataFrame) -> str:
    """A plain escaped HTML table of a small frame (numbers to 4 significant digits)."""
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in frame.columns)
    body = []
    for row in frame.itertuples(index=False):
        cells = [f"{v:.4g}" if isinstance(v, (float, np.floating)) else str(v) for v in row]
        body.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    return f"<table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n" + "\n".join(body) + "\n</tbody>\n</table>\n"


def _synthetic(dataset: str) -> bool:
    from enginebench.datasets import catalog

    builtin = catalog.builtin_datasets().get(str(dataset))
    return builtin is not None and builtin.kind == "synthetic"


def _page(run: Run, summary: pd.DataFrame, metrics_cols: Sequence[str], paired: pd.DataFrame | None,
          paired_metric: str, curve_text: str | None, figures: list[Figure], notes: list[str], out: Path,
          interactive: str | None = None, verdict: Sequence[Verdict] = ()) -> str:
    info, cfg = run.info(), run.config()
    env_text = (run.path / "environment.json").read_text() if (run.path / "environment.json").is_file() else "{}"
    cfg_text = (run.path / "config.toml").read_text()
    esc = html.escape
    parts = [f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>enginebench report: {esc(run.id)}</title>\n"
             f"<style>{_STYLE}</style>\n</head>\n<body>\n<h1>Run {esc(run.id)}</h1>\n", verdict_html(verdict)]
    parts.append(f"<p>experiment <b>{esc(str(cfg.get('name', '?')))}</b> on dataset <b>{esc(str(cfg.get('dataset', '?')))}</b>"
                 f" {esc(str(cfg.get('dataset_variant', '')))}; targets {esc(', '.join(map(str, cfg.get('targets', []))))}; "
                 f"mode {esc(str(cfg.get('mode', '?')))}; {esc(str(cfg.get('repetitions', '?')))} repetitions, seed "
                 f"{esc(str(cfg.get('seed', '?')))}; status {esc(str(info.get('status', '?')))}, "
                 f"{len(run.job_files())}/{esc(str(info.get('n_jobs', '?')))} jobs, "
                 f"{esc(str(info.get('failed_jobs', 0)))} failed; created {esc(str(info.get('created', '?')))}</p>\n")
    if interactive:
        parts.append(f"<p>Interactive version (zoomable plots, sortable table): <a href=\"{esc(interactive)}\">"
                     f"{esc(interactive)}</a></p>\n")
    if _synthetic(cfg.get("dataset", "")):
        parts.append("<p class=\"synthetic\">SYNTHETIC data (generated by enginebench): not measurements of a real engine.</p>\n")
    parts.append(f"<h2>Comparison table</h2>\n{tables.to_html(summary, metrics_cols, units=run_units(info))}"
                 f"<p>The long table with every metric: <a href=\"{TABLE_FILE}\">{TABLE_FILE}</a></p>\n")
    items = run_note_lines(run)
    if items:
        parts.append("<h2>Failures and warnings</h2>\n<ul>\n"
                     + "".join(f"<li class=\"note\">{esc(i)}</li>\n" for i in items) + "</ul>\n")
    parts.append(f"<h2>Paired tests on {esc(paired_metric or '-')}</h2>\n")
    if paired is None or paired.empty:
        parts.append("<p class=\"note\">no paired tests (one method per block, too few repetitions, or none asked for)</p>\n")
    else:
        parts.append("<p>each method against the best method of its block, paired on repetitions</p>\n" + _frame_html(paired))
    if curve_text is not None:
        parts.append(f"<h2>Learning curve</h2>\n<pre>{esc(curve_text)}</pre>\n")
    parts.append("<h2>Figures</h2>\n")
    titles = {"learning-curve": "Learning curve", "trend": "Time trends", "trajectory": "Trajectories",
              "scatter": "Measured vs predicted"}
    for kind, title in titles.items():
        chosen = [f for f in figures if f.kind == kind]
        if not chosen:
            continue
        parts.append(f"<h3>{title}</h3>\n")
        for f in chosen:
            rel = f.path.relative_to(out).as_posix()
            parts.append(f"<figure><img src=\"{esc(rel)}\" alt=\"{esc(f.caption)}\"><figcaption>{esc(f.caption)}"
                         "</figcaption></figure>\n")
    if not figures:
        parts.append("<p class=\"note\">no figures</p>\n")
    if notes:
        parts.append("<h2>Notes</h2>\n<ul>\n" + "".join(f"<li class=\"note\">{esc(n)}</li>\n" for n in notes) + "</ul>\n")
    parts.append(f"<h2>Run info</h2>\n<pre>{esc(json.dumps(info, indent=2))}</pre>\n"
                 f"<h2>Config</h2>\n<pre>{esc(cfg_text)}</pre>\n<h2>Environment</h2>\n<pre>{esc(env_text)}</pre>\n")
    parts.append("</body>\n</html>\n")
    return "".join(parts)


def write_report(
    run: Run,
    out_dir: str | Path,
    *,
    paired_metric: str | None = None,
    max_rows: int = MAX_ROWS,
    interactive: str | None = None,
    **settings: Any,
) -> ReportResult:
    """Write ``out_dir/index.html`` with ``run``'s tables, settings and PNG figures beside it.

    ``settings``: the keywords of ``ReportSettings``; ``figures=False`` writes the tables
    only (no data loaded, no re-fit), figures needing predictions re-fit ``repetition`` on
    ``part`` (see the module docstring). ``paired_metric``: of the paired tests (default
    rmse in simulation mode, mae otherwise; '' skips them). ``interactive``: the file name
    of an interactive report written beside it, linked from the page.
    """
    opts = ReportSettings(**settings)
    repetition, part, methods = opts.repetition, opts.part, opts.methods
    if repetition < 0:
        raise MethodError(f"repetition must be >= 0, got {repetition}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cfg = run.config()
    raw = run.metrics()
    summary = tables.summarize(raw, interval=opts.interval or cfg.get("interval", "t"))
    metrics = list(opts.metrics) if opts.metrics else tables.default_metrics(summary)
    if paired_metric is None:
        paired_metric = tables.default_paired_metric(cfg.get("mode", ""))
    table_path = out / TABLE_FILE
    table_path.write_text(tables.to_csv(summary, units=run_units(run.info())), encoding="utf-8")
    paired = tables.paired_tests(raw, paired_metric) if paired_metric else None
    found = run_verdicts(run, raw, summary, paired, paired_metric)
    result = ReportResult(index=out / REPORT_FILE, table=table_path)
    curve_text = None
    curve = is_learning_curve(run)
    if curve:
        from enginebench.experiments.learning_curve import curve_table, plot_curve, summarize_curve

        curve_summary = summarize_curve(raw)
        curve_text = curve_table(curve_summary)
        if opts.figures and not curve_summary.empty:
            path = plot_curve(curve_summary, out / "learning_curve.png")
            if path is not None:
                result.figures.append(Figure(path, "learning-curve", "test MAE against months of training data "
                                                                     "(mean ± Student-t 95% half-width over repetitions)"))
    if opts.figures and curve:
        result.notes.append("learning-curve run: prediction figures are not drawn (each amount of data is its own model)")
    elif opts.figures:
        try:
            if cfg.get("mode") == "simulation":
                drawn, notes, result.simulated = simulation_figures(run, out, methods, part, repetition,
                                                                    opts.trajectories)
            else:
                preds, notes = refit_predictions(run, repetition=repetition, part=part, methods=methods, max_rows=max_rows)
                result.predictions = preds
                drawn = prediction_figures(preds, out, run)
            result.figures += drawn
            result.notes += notes
        except EngineBenchError as exc:
            if methods:  # the user named them: a bad name is an error, not a note
                raise
            result.notes.append(f"prediction figures skipped: {exc}")
    missing = [f.path for f in result.figures if not f.path.is_file()]
    if missing:  # pragma: no cover - the plot functions return what they saved
        raise EngineBenchError(f"report: figure(s) not written: {', '.join(map(str, missing))}")
    result.index.write_text(_page(run, summary, metrics, paired, paired_metric, curve_text, result.figures,
                                  result.notes, out, interactive, found), encoding="utf-8")
    return result
