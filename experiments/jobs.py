"""One job of a run: (target, window, split, method, repetition) -> metric rows.

A job is deterministic given the experiment and its coordinates: the training subsample
depends only on (seed, repetition, split), so every method of a repetition sees the same
rows and the methods can be compared pairwise; the method's own draws depend on
(seed, repetition, method).
"""

from __future__ import annotations

import time
import traceback
import warnings
import zlib
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import pandas as pd

from enginebench.datasets.pools import SamplePool
from enginebench.errors import MethodError
from enginebench.experiments.keep import after_test
from enginebench.experiments.selection import select
from enginebench.experiments.spec import ExperimentSpec
from enginebench.method import Method
from enginebench.results.job_files import SELECTION_META
from enginebench.results.metrics import compute_metrics, mean_abs, per_segment
from enginebench.results.summary import SELECTED_PREFIX
from enginebench.samples import Samples


JOINT = "(all targets)"
"""The target of a job that fits every target of the experiment at once (``joint_targets``)."""


@dataclass(frozen=True)
class Job:
    target: str
    window: float
    split: str
    method: str
    repetition: int

    @property
    def key(self) -> str:
        """The job's file name: injective (two jobs never share a file), and plain names stay as they are."""
        return (f"{key_part(self.target)}__w{window_part(self.window)}__{key_part(self.split)}__"
                f"{key_part(self.method)}__r{self.repetition:03d}")


PLAIN = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-._")


def key_part(name: str) -> str:
    """``name`` in a job key: ASCII letters, digits, '-', '.', '_' as they are, every other character as
    ``~XX`` per UTF-8 byte ('~' included), and every '_' too when the name holds '__' or starts or ends with
    '_'. Decoding is unique and an encoded part never holds the '__' that separates parts, so different
    (target, window, split, method, repetition) never give one key ("y a" -> y~20a, "y-a" -> y-a)."""
    underscores = "__" in name or name.startswith("_") or name.endswith("_")
    out = []
    for ch in name:
        if ch in PLAIN and not (ch == "_" and underscores):
            out.append(ch)
        else:
            out.extend(f"~{b:02X}" for b in ch.encode("utf-8"))
    return "".join(out) or "~"


def window_part(window: float) -> str:
    """A window in a job key: ``%g`` (as keys always were) unless that loses digits, then the exact repr."""
    short = f"{window:g}"
    return short if float(short) == window else repr(float(window))


@dataclass(frozen=True)
class Problem:
    """The samples of one (target, window, split): the training pool and the evaluated parts.

    A plan over the runner may add job coordinates of its own through the split name
    (e.g. a learning curve's ``published@3mo``, one problem per amount of training
    data): ``train_size`` then replaces the experiment's, ``coordinates`` become columns
    of every metric row and entries of the job's metadata (with ``n_train``, the rows the
    job was fitted on), and ``label`` is appended to the scored parts' names (``test@3mo``).
    """

    train: Samples | SamplePool
    parts: dict[str, Samples | SamplePool]
    train_size: int | None = None
    coordinates: dict[str, Any] = field(default_factory=dict)
    label: str = ""


@dataclass
class Context:
    """Everything a worker needs, prepared once in the parent."""

    spec: ExperimentSpec
    dataset: str
    problems: dict[tuple[str, float, str], Problem]
    methods: dict[str, Method]
    dataset_hash: str = ""
    finish: Callable[[Any], None] | None = None
    """Called with the run once every job is stored (a learning curve writes its summary table)."""
    coverage: dict[str, Any] = field(default_factory=dict)
    """Where the evaluated records' inputs or outputs leave the training range (``experiments/coverage.py``),
    for run.json."""


def joint_methods(spec: ExperimentSpec, methods: dict[str, Method]) -> set[str]:
    """The methods that fit all targets in one job: ``joint_targets`` asked for, several targets, and the
    method declares it can."""
    if not spec.joint_targets or len(spec.targets) < 2:
        return set()
    return {name for name, m in methods.items() if getattr(m, "joint_targets", False)}


def job_for(ctx: Context, target: str, window: float, split: str, method: str, repetition: int
            ) -> tuple[Job, Problem, int]:
    """The job that scored ``method`` on ``target``, its problem and the target's column in its samples:
    the target's own job, or the joint job of a method that fitted all targets at once."""
    joint = (JOINT, window, split)
    if joint in ctx.problems and method in joint_methods(ctx.spec, ctx.methods):
        return Job(JOINT, window, split, method, repetition), ctx.problems[joint], list(ctx.spec.targets).index(target)
    return Job(target, window, split, method, repetition), ctx.problems[(target, window, split)], 0


def stable_int(text: str) -> int:
    return zlib.crc32(text.encode())


def subsample(n: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted row positions of a training subsample without replacement (all rows if size is 0 or >= n)."""
    if size <= 0 or size >= n:
        return np.arange(n)
    return np.sort(rng.choice(n, size=size, replace=False))


def subsample_segments(sizes: np.ndarray, size: int, rng: np.random.Generator) -> np.ndarray:
    """Row positions of whole segments drawn at random until ``size`` rows are reached (all if 0)."""
    edges = np.r_[0, np.cumsum(sizes)]
    if size <= 0 or size >= edges[-1]:
        return np.arange(edges[-1])
    order = rng.permutation(len(sizes))
    keep = order[: int(np.searchsorted(np.cumsum(np.asarray(sizes)[order]), size)) + 1]
    return np.concatenate([np.arange(edges[k], edges[k + 1]) for k in np.sort(keep)])


def training_samples(spec: ExperimentSpec, problem: Problem, repetition: int, split: str) -> Samples:
    """A repetition's training subsample: it depends only on (seed, repetition, split), so methods pair up.

    In simulation mode a trajectory is only usable whole, so whole segments are drawn.
    """
    sub_rng = np.random.default_rng([spec.seed, repetition, stable_int(split)])
    size = train_size(spec, problem)
    if spec.mode == "simulation":
        return problem.train.take(subsample_segments(problem.train.segment_sizes, size, sub_rng))
    return problem.train.take(subsample(len(problem.train), size, sub_rng))


def train_size(spec: ExperimentSpec, problem: Problem) -> int:
    """The training subsample size of a problem: its own (a learning curve's amount) or the experiment's."""
    return spec.train_size if problem.train_size is None else problem.train_size


def refit_samples(spec: ExperimentSpec, problem: Problem, train: Samples, repetition: int, split: str) -> Samples:
    """What the selected point is fitted on: the training subsample, plus the validation part after a validation selection.

    ``[selection] refit = true`` (the default) adds the validation part once it has served
    to select (all of it in simulation mode, whole records from their first sample; in
    static and window modes a subsample of ``train_size`` rows drawn like the training one).
    ``refit = false`` keeps the fit on the training part only (the turboshaft-moe paper's protocol).
    """
    part = problem.parts.get("validation")
    if not (spec.selection.refit and spec.selection.kind == "validation" and part is not None):
        return train
    if spec.mode == "simulation":
        raw = getattr(part, "raw", None)
        whole = (SamplePool(raw, part.target_names, spec.mode, part.window, physical_model=part.physical_model)
                 .materialize() if raw is not None else part.materialize())
        return train.joined(whole)
    rng = np.random.default_rng([spec.seed, repetition, stable_int(split), stable_int("validation")])
    return train.joined(part.take(subsample(len(part), train_size(spec, problem), rng)))


def method_rng(spec: ExperimentSpec, job: Job) -> np.random.Generator:
    """The generator of a job's selection draws (folds, search points, the candidates' own draws): depends on
    (seed, repetition, method)."""
    return np.random.default_rng([spec.seed, job.repetition, stable_int(job.method)])


def final_fit_rng(spec: ExperimentSpec, job: Job) -> np.random.Generator:
    """The generator of a job's final fit: its own stream, not what selection left of ``method_rng``'s, so a
    stored job's model can be fitted again without replaying selection (``refit_stored_job``)."""
    return np.random.default_rng([spec.seed, job.repetition, stable_int(job.method), stable_int("final fit")])


def refit_stored_job(ctx: Context, job: Job, meta: dict[str, Any], train: Samples) -> Any:
    """Fit a stored job's method again on ``train`` with the hyperparameters the job selected.

    For figures and reports: the job's final fit drew from ``final_fit_rng``, as this fit does, so a
    method reproduces the job's model exactly, random draws (Nystroem centres, initial weights) included, on
    the same machine and library versions. Except where the job tested the selection's own model
    (``meta["tested_selected_model"]``, with ``refit = false``): that model was drawn during selection and
    this fit draws afresh. MethodError when the job failed in the run.
    """
    if meta.get("status") != "ok":
        raise MethodError(f"repetition {job.repetition} failed in the run ({meta.get('reason', '?')})")
    return ctx.methods[job.method].fit(train, meta.get("params", {}), final_fit_rng(ctx.spec, job))


PREDICT_BATCH_ROWS = 20_000
"""Rows predicted at a time in static and window modes: bounds the feature and kernel blocks of a job."""


def predict_part(method: Method, fitted: Any, part: "Samples | SamplePool", mode: str
                 ) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """(truth, predictions, diverged flags) per segment of an evaluated part.

    Simulating methods see whole trajectories at once; in static and window modes the
    part is predicted in row blocks of ``PREDICT_BATCH_ROWS`` (features are built per
    block), so a million-row test period never sits in memory as one feature matrix.
    """
    if mode == "simulation":
        data = part.materialize()
        preds = method.predict(fitted, data.without_targets())
        guess = [np.asarray(p, dtype=float).reshape(len(s), -1) for p, s in zip(preds, data.segments)]
        diverged = np.asarray(getattr(preds, "diverged", np.zeros(len(preds), bool)))
        return [s.y for s in data.segments], guess, diverged
    truth, guess = [], []
    for batch in part.batches(PREDICT_BATCH_ROWS, method.uses_features):
        preds = method.predict(fitted, batch.without_targets())
        k = len(batch.target_names)
        guess.append(np.concatenate([np.asarray(p, dtype=float).reshape(len(s), k) for p, s in zip(preds, batch.segments)])
                     if batch.segments else np.empty((0, k)))
        truth.append(batch.y)
    if not truth:
        return [], [], np.zeros(0, dtype=bool)
    cuts = np.cumsum(part.segment_sizes)[:-1]
    return (np.split(np.concatenate(truth), cuts), np.split(np.concatenate(guess), cuts),
            np.zeros(len(part.segment_sizes), dtype=bool))


def one_line_reason(exc: BaseException, limit: int = 300) -> str:
    """``Type: message`` on one line, cut to ``limit`` characters (a failed job's reason as tables show it)."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def run_job(ctx: Context, job: Job) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Run one job; failures become a 'failed' record with the reason, never an exception.

    Returns (metric rows, metadata); after a selection over a grid the metadata carries the
    job's selection table (a DataFrame under ``results.store.SELECTION_META``), which
    ``Run.write_job`` stores as the job's selection file.
    """
    spec = ctx.spec
    problem = ctx.problems[(job.target, job.window, job.split)]
    method = ctx.methods[job.method]
    base = {"dataset": ctx.dataset, "target": job.target, "mode": spec.mode, "window": job.window,
            "method": job.method, "family": method.family, "repetition": job.repetition}
    meta: dict[str, Any] = {"job": job.key, **base, "split": job.split}
    timings: dict[str, float] = {}
    rows: list[dict[str, Any]] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for quiet in (DeprecationWarning, PendingDeprecationWarning, FutureWarning):  # library upkeep, not the result's
            warnings.simplefilter("ignore", quiet)
        rows = _run_job(ctx, job, spec, problem, method, base, meta, timings)
    heard = caught_warnings(caught)
    if heard and meta["status"] == "ok":
        meta["warnings"] = [*meta.get("warnings", []), *(f"{job.method}: {w}" for w in heard)]
    meta["timings"] = timings
    if not rows:
        rows.append({**base, "split": "-", "metric": "failed", "value": float("nan")})
    for name, value in timings.items():
        rows.append({**base, "split": "-", "metric": f"time_{name}", "value": value})
    score = (meta.get("search") or {}).get("best_score") if meta.get("status") == "ok" else None
    if isinstance(score, float) and np.isfinite(score):  # the selected point's validation score, beside its test one
        rows.append({**base, "split": "-", "metric": f"{SELECTED_PREFIX}{spec.selection.criterion}", "value": score})
    frame = pd.DataFrame(rows)
    frame["status"] = meta["status"]
    if problem.coordinates:
        meta.update(problem.coordinates)
        frame = frame.assign(**problem.coordinates, n_train=int(meta.get("n_train", -1)))
    if problem.label:
        scored = frame["split"] != "-"
        frame.loc[scored, "split"] = frame.loc[scored, "split"] + problem.label
    return frame, meta


def selection_frame(frame: pd.DataFrame, job: Job) -> pd.DataFrame:
    """A selection table (``SelectionTable.frame``) with the job's coordinates in front, as ``Run.selection_table`` reads it."""
    coords = {"target": job.target, "window": float(job.window), "split": job.split, "method": job.method,
              "repetition": int(job.repetition)}
    return pd.concat([pd.DataFrame(coords, index=frame.index), frame], axis=1)


MAX_JOB_WARNINGS = 5
"""Distinct Python warnings kept per job (the first ones; a count says how many more)."""


def caught_warnings(caught: list[warnings.WarningMessage]) -> list[str]:
    """Distinct warnings raised while a job ran, ``Category: message (n times)``, at most ``MAX_JOB_WARNINGS``.

    Numerical warnings of method code (numpy overflow, ill-conditioning...) become job
    warnings, listed with the run's other notes, instead of reaching the terminal unexplained.
    """
    counts: dict[str, int] = {}
    for w in caught:
        text = " ".join(f"{w.category.__name__}: {w.message}".split())
        counts[text[:200]] = counts.get(text[:200], 0) + 1
    out = [f"{text} ({n} times)" if n > 1 else text for text, n in counts.items()]
    return out[:MAX_JOB_WARNINGS] + ([f"... and {len(out) - MAX_JOB_WARNINGS} other warning(s)"]
                                      if len(out) > MAX_JOB_WARNINGS else [])


MAX_RECORDED_SEGMENTS = 200
"""Parts with at most this many segments keep each segment's RMSE, NRMSE and MAE in the job's metadata
(``meta["segments"]``), for the per-record tables; longer lists of short segments are summarised only."""


def _run_job(ctx: Context, job: Job, spec: ExperimentSpec, problem: Problem, method: Method,
             base: dict[str, Any], meta: dict[str, Any], timings: dict[str, float]) -> list[dict[str, Any]]:
    """The body of ``run_job``: metric rows, with ``meta`` and ``timings`` filled in; never raises."""
    rows: list[dict[str, Any]] = []
    try:
        train = training_samples(spec, problem, job.repetition, job.split)
        rng = method_rng(spec, job)
        t0 = time.perf_counter()
        validation = problem.parts["validation"].materialize() if "validation" in problem.parts else None
        fit_on = refit_samples(spec, problem, train, job.repetition, job.split)
        params, search = select(method, train, spec.selection, rng, validation, spec.init_samples,
                                keep_fitted=fit_on is train)
        timings["select_s"] = time.perf_counter() - t0
        table = search.pop("table", None)
        if table is not None:  # the store writes it as the job's selection file (Run.write_job)
            meta[SELECTION_META] = selection_frame(table.frame(), job)
        t0 = time.perf_counter()
        fitted = search.pop("fitted", None)
        meta["tested_selected_model"] = fitted is not None
        if fitted is None:
            fitted = method.fit(fit_on, params, final_fit_rng(spec, job))
        timings["fit_s"] = time.perf_counter() - t0
        scale = mean_abs(fit_on.y)  # exact-scaled: no overflow near 1e308
        described = method.describe(fitted)
        warnings = [*search.pop("warnings", []), *[f"{job.method}: {w}" for w in described.get("warnings", []) or []]]
        meta.update(params=params, search=search, describe=described, n_train=len(fit_on),
                    refit_on_validation=fit_on is not train)
        if warnings:
            meta["warnings"] = warnings
        predicted: dict[str, list[np.ndarray]] = {}
        for part_name, part in problem.parts.items():
            t0 = time.perf_counter()
            truth_all, guess_all, diverged = predict_part(method, fitted, part, spec.mode)
            timings[f"predict_{part_name}_s"] = time.perf_counter() - t0
            predicted[part_name] = guess_all
            for k, name in enumerate(part.target_names):
                truth = [y[:, k] for y in truth_all]
                guess = [g[:, k] for g in guess_all]
                bad = [sid for sid, g in zip(part.segment_ids(), guess) if not np.all(np.isfinite(g))]
                if bad:
                    raise FloatingPointError(
                        f"{job.method} returned non-finite predictions for {len(bad)} segment(s) of the {part_name} part "
                        f"(first: {bad[0]})"
                    )
                values, notes = compute_metrics(truth, guess, scale)
                if len(truth) <= MAX_RECORDED_SEGMENTS:  # where in the campaign the error lies: one entry per record
                    kept = meta.setdefault("segments", {}).setdefault(part_name, {"ids": list(part.segment_ids())})
                    kept[name] = per_segment(truth, guess)
                values["diverged"] = float(diverged.sum())
                for metric, value in values.items():
                    rows.append({**base, "target": name, "split": part_name, "metric": metric, "value": float(value)})
                if notes:
                    meta.setdefault("notes", {}).update({f"{part_name}:{k}": v for k, v in notes.items()})
        for row in after_test(spec, job, method, fitted, problem, params, meta, predicted, timings):  # experiments/keep.py
            rows.append({**base, "split": "test", **row})
        meta["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - whatever method code raises is that job's failure, with its reason
        rows = []
        meta.pop("warnings", None)
        meta.update(status="failed", reason=one_line_reason(exc), traceback=traceback.format_exc(limit=8))
    return rows
