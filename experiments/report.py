"""An HTML report of a stored run: its tables, its settings and PNG figures, in one folder.

``write_report(run, DIR)`` writes ``DIR/index.html`` and, beside it, the comparison table
as csv and the figures as PNG files referenced by relative names, so the folder can be
copied, zipped or logged as one artefact:

- the comparison table (``results.tables``), the paired tests of every method against
  its block's best, and the run's info, config and environment;
- measured vs predicted scatters and time trends of the evaluated part (test by
  default). Predictions are not stored in a run, so they come from re-fitting one
  repetition: a simulation run is redrawn by ``experiments.plots_run.plot_run``
  (trajectories, with gate bands underneath from the first method whose ``explain``
  hook declares mixing weights, e.g. a mixture of experts); in
  static and window modes each method is fitted again on that repetition's training
  subsample with the hyperparameters the run selected (``refit_predictions``);
- the learning curve, for a run made by ``enginebench learning-curve``.

A figure that cannot be drawn (a missing dataset, a failed re-fit) is skipped with a
note in the page, never silently.
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
from enginebench.results import tables
from enginebench.results.notes import run_note_lines
from enginebench.results.store import Run
from enginebench.results.units import run_units

REPORT_FILE = "index.html"
TABLE_FILE = "table.csv"
MAX_ROWS = 20_000
"""Most rows of the evaluated part predicted for the static/window figures (evenly thinned beyond)."""
REFIT_ERRORS = (EngineBenchError, ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError)


@dataclass(frozen=True)
class Figure:
    """One PNG of the report: its path, kind (scatter, trend, trajectory, learning-curve) and caption."""

    path: Path
    kind: str
    caption: str


@dataclass
class Predictions:
    """One method re-fitted for one repetition, predicted on the rows drawn of one evaluated part."""

    target: str
    window: float
    split: str
    method: str
    part: str
    repetition: int
    time: np.ndarray
    """Time stamps (seconds, the dataset's time axis) of the predicted rows, in order."""
    truth: np.ndarray
    pred: np.ndarray
    segment: np.ndarray
    """Segment index of each row (lines break between segments)."""
    diverged: np.ndarray | None = None
    """Per row: True on the segments whose free run left its envelope (``SegmentPredictions.diverged``)."""
    weights: np.ndarray | None = None
    """(rows, k) mixing weights from the method's ``explain`` hook, or None when it declares none."""


@dataclass
class ReportResult:
    """What ``write_report`` wrote: the page, its figures, and the notes shown in it."""

    index: Path
    table: Path
    figures: list[Figure] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    predictions: list[Predictions] = field(default_factory=list)
    simulated: list = field(default_factory=list)
    """Simulation runs: the re-fitted trajectories drawn (``plots_run.Simulated``)."""


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


def _safe(text: str) -> str:
    import re

    return re.sub(r"[^A-Za-z0-9._-]+", "-", str(text)).strip("-")


def is_learning_curve(run: Run) -> bool:
    """True for a run written by ``enginebench learning-curve`` (its config carries the curve settings)."""
    return "learning_curve" in run.config()


# -- predictions --------------------------------------------------------------------

def refit_predictions(
    run: Run,
    *,
    repetition: int = 0,
    part: str = "test",
    methods: Sequence[str] | None = None,
    max_rows: int = MAX_ROWS,
) -> tuple[list[Predictions], list[str]]:
    """Re-fit the methods of a static or window run for one repetition and predict ``part``.

    Each method is fitted on the training subsample the run drew for that repetition and
    split (the same seeds as the run's job) with the hyperparameters the job selected, so
    a deterministic method reproduces the job's predictions exactly; a stochastic one
    draws afresh (selection is not replayed). Parts longer than ``max_rows`` are thinned
    to evenly spaced rows. Returns the predictions and notes on what was skipped.
    """
    from enginebench.experiments.jobs import Job, refit_stored_job, training_samples
    from enginebench.experiments.plots_run import weights_of
    from enginebench.experiments.runner import prepare
    from enginebench.experiments.spec import from_dict

    spec = from_dict(run.config(), origin=f"run {run.id}")
    if spec.mode == "simulation":
        raise MethodError(f"run {run.id} is a simulation run; its trajectories are redrawn by 'enginebench plots'")
    if max_rows < 1:
        raise MethodError(f"max_rows must be >= 1, got {max_rows}")
    ctx = prepare(spec)
    chosen = list(methods) if methods else list(spec.methods)
    unknown = [m for m in chosen if m not in ctx.methods]
    if unknown:
        raise MethodError(f"run {run.id} did not run method(s) {', '.join(unknown)}; it ran {', '.join(ctx.methods)}")
    out: list[Predictions] = []
    notes: list[str] = []
    for (target, window, split), problem in ctx.problems.items():
        if part not in problem.parts:
            notes.append(f"{target}, window {window:g} s, split {split}: no {part!r} part; not drawn")
            continue
        train = training_samples(spec, problem, repetition, split)
        evaluated = problem.parts[part]
        n = len(evaluated)
        rows = np.arange(n) if n <= max_rows else np.unique(np.linspace(0, n - 1, max_rows).round().astype(np.int64))
        if n > max_rows:
            notes.append(f"{target}, window {window:g} s, {split}: {max_rows} of {n} {part} rows drawn (evenly spaced)")
        shown = evaluated.take(rows)
        time = np.concatenate([s.t[s.rows] for s in shown.segments])
        truth = shown.y[:, 0]
        segment = np.concatenate([np.full(len(s), k) for k, s in enumerate(shown.segments)])
        for name in chosen:
            where = f"{name} ({target}, window {window:g} s, {split}, repetition {repetition})"
            job = Job(target, window, split, name, repetition)
            try:
                fitted = refit_stored_job(ctx, job, run.job_meta(job.key), train)
                preds = ctx.methods[name].predict(fitted, shown.without_targets())
                pred = np.concatenate([np.asarray(p, dtype=float).reshape(len(s), -1)[:, 0]
                                       for p, s in zip(preds, shown.segments)])
                weights = weights_of(ctx.methods[name], fitted, shown.without_targets())
            except REFIT_ERRORS as exc:
                notes.append(f"{where}: re-fit failed ({type(exc).__name__}: {exc}); not drawn")
                continue
            flags = getattr(preds, "diverged", None)
            out.append(Predictions(target, window, split, name, part, repetition, time, truth, pred, segment,
                                   None if flags is None else np.asarray(flags, dtype=bool)[segment],
                                   None if weights is None else np.concatenate(weights)))
    return out, notes


def _time_axis(seconds: np.ndarray) -> tuple[np.ndarray, str]:
    """Time since the first row in a readable unit."""
    rel = seconds - seconds.min() if seconds.size else seconds
    span = float(rel.max()) if rel.size else 0.0
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if span >= 3 * size:
            return rel / size, unit
    return rel, "s"


def time_trend_plot(predictions: Sequence[Predictions], path: str | Path, *, title: str = "",
                    size: tuple[float, float] = (11.0, 4.5), dpi: int = 100) -> Path:
    """Measured and predicted (one line per method) over time on the shared rows; lines break between segments.

    All ``predictions`` must share the same rows (one (target, window, split, part)).
    Returns the PNG path.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure as MplFigure

    if not predictions:
        raise MethodError("time trend: no predictions to draw")
    first = predictions[0]
    for p in predictions[1:]:
        if p.time.shape != first.time.shape or not np.array_equal(p.time, first.time):
            raise MethodError("time trend: the predictions do not share the same rows")
    x, unit = _time_axis(first.time)
    breaks = np.flatnonzero(np.diff(first.segment) != 0) + 1

    def broken(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # NaN between segments: no joining line
        return np.insert(x.astype(float), breaks, np.nan), np.insert(values.astype(float), breaks, np.nan)

    fig = MplFigure(figsize=size, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot(*broken(first.truth), color="black", lw=1.2, label="measured")
    styles = ["-", "--", ":", "-."]
    for k, p in enumerate(predictions):
        ax.plot(*broken(p.pred), lw=0.9, ls=styles[k % len(styles)], label=p.method)
    ax.set_xlabel(f"time since the first {first.part} row ({unit})")
    ax.set_ylabel(first.target)
    ax.legend(loc="best", fontsize="small", ncols=min(4, len(predictions) + 1))
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def _prediction_figures(predictions: list[Predictions], out: Path, run: Run) -> list[Figure]:
    from enginebench.results.plots import scatter_plot

    figures = []
    groups: dict[tuple, list[Predictions]] = {}
    for p in predictions:
        groups.setdefault((p.target, p.window, p.split, p.part), []).append(p)
    for (target, window, split, part), group in groups.items():
        stem = f"{_safe(target)}__w{window:g}__{_safe(split)}"
        rep = group[0].repetition
        path = time_trend_plot(group, out / f"{stem}__trend.png",
                               title=f"{target}, window {window:g} s, {split}: {part} part (run {run.id}, "
                                     f"repetition {rep}, re-fitted)")
        figures.append(Figure(path, "trend", f"{target}, window {window:g} s, split {split}: measured and predicted "
                                             f"over time on the {part} part (repetition {rep}, re-fitted)"))
        for p in group:
            path = scatter_plot(p.truth, p.pred, out / f"{stem}__scatter__{_safe(p.method)}.png",
                                title=f"{p.method}: {target}, window {window:g} s, {split} {part}",
                                label=target)
            figures.append(Figure(path, "scatter", f"{p.method}: measured vs predicted {target}, window {window:g} s, "
                                                   f"split {split}, {part} part (repetition {rep}, re-fitted)"))
    return figures


def _simulation_figures(run: Run, out: Path, methods, part: str, repetition: int, trajectories: int
                        ) -> tuple[list[Figure], list[str], list]:
    from enginebench.experiments.plots_run import plot_run

    drawn = plot_run(run, out, list(methods) if methods else None, trajectories=trajectories, part=part,
                     repetition=repetition)
    figures = []
    for path in drawn.paths:
        if "__scatter__" in path.name:
            figures.append(Figure(path, "scatter", f"measured vs simulated, {part} trajectories shown: "
                                                   f"{path.stem.split('__scatter__')[-1]} (repetition {repetition}, re-fitted)"))
        else:
            banded = drawn.bands.get(path)
            figures.append(Figure(path, "trajectory", f"simulated vs true on a {part} trajectory (repetition {repetition}, "
                                                      "re-fitted)" + (f"; {banded} gate weights as bands underneath"
                                                                      if banded else "")))
    return figures, list(drawn.notes), drawn.simulated


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
"""


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

    builtin = catalog.BUILTINS.get(str(dataset))
    return builtin is not None and builtin.kind == "synthetic"


def _page(run: Run, summary: pd.DataFrame, metrics_cols: Sequence[str], paired: pd.DataFrame | None,
          paired_metric: str, curve_text: str | None, figures: list[Figure], notes: list[str], out: Path,
          interactive: str | None = None) -> str:
    info, cfg = run.info(), run.config()
    env_text = (run.path / "environment.json").read_text() if (run.path / "environment.json").is_file() else "{}"
    cfg_text = (run.path / "config.toml").read_text()
    esc = html.escape
    parts = [f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>enginebench report: {esc(run.id)}</title>\n"
             f"<style>{_STYLE}</style>\n</head>\n<body>\n<h1>Run {esc(run.id)}</h1>\n"]
    parts.append(f"<p>experiment <b>{esc(str(cfg.get('name', '?')))}</b> on dataset <b>{esc(str(cfg.get('dataset', '?')))}</b>"
                 f" {esc(str(cfg.get('dataset_variant', '')))}; targets {esc(', '.join(map(str, cfg.get('targets', []))))}; "
                 f"mode {esc(str(cfg.get('mode', '?')))}; {esc(str(cfg.get('repetitions', '?')))} repetitions, seed "
                 f"{esc(str(cfg.get('seed', '?')))}; status {esc(str(info.get('status', '?')))}, "
                 f"{esc(str(info.get('finished_jobs', len(run.finished_jobs()))))}/{esc(str(info.get('n_jobs', '?')))} jobs, "
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
                drawn, notes, result.simulated = _simulation_figures(run, out, methods, part, repetition,
                                                                     opts.trajectories)
            else:
                preds, notes = refit_predictions(run, repetition=repetition, part=part, methods=methods, max_rows=max_rows)
                result.predictions = preds
                drawn = _prediction_figures(preds, out, run)
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
                                  result.notes, out, interactive), encoding="utf-8")
    return result
