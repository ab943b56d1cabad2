"""The predictions behind the report's static/window figures: each method re-fitted for one repetition.

Predictions are not stored in a run, so ``refit_predictions`` fits each method of a
static or window run again on that repetition's training subsample with the
hyperparameters the run selected, and predicts the evaluated part (thinned to
``MAX_ROWS``). Both reports draw from them: ``static.write_report`` (PNG figures, through
``static_figures``) and ``interactive.write_interactive_report``. Kept apart from
the pages so that what is predicted is one job and how it is shown another.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from enginebench.errors import EngineBenchError, MethodError
from enginebench.results.run_folder import Run

MAX_ROWS = 20_000
"""Most rows of the evaluated part predicted for the static/window figures (evenly thinned beyond)."""
REFIT_ERRORS = (EngineBenchError, ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError)


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
    a method reproduces the job's predictions exactly, its random draws included (the final fit has
    its own generator; selection is not replayed). Parts longer than ``max_rows`` are thinned
    to evenly spaced rows. Returns the predictions and notes on what was skipped.
    """
    from enginebench.experiments.jobs import JOINT, job_for, refit_stored_job, training_samples
    from enginebench.experiments.spec import from_dict
    from enginebench.reports.trajectories import prepared, weights_of

    spec = from_dict(run.config(), origin=f"run {run.id}")
    if spec.mode == "simulation":
        raise MethodError(f"run {run.id} is a simulation run; its trajectories are redrawn by 'enginebench plots'")
    if max_rows < 1:
        raise MethodError(f"max_rows must be >= 1, got {max_rows}")
    ctx, chosen = prepared(run, spec, methods)
    out: list[Predictions] = []
    notes: list[str] = []
    for (target, window, split), problem in ctx.problems.items():
        if target == JOINT:  # drawn target by target below
            continue
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
            job, own, col = job_for(ctx, target, window, split, name, repetition)
            fit_on, given = (train, shown) if own is problem else (
                training_samples(spec, own, repetition, split), own.parts[part].take(rows))
            try:
                fitted = refit_stored_job(ctx, job, run.job_meta(job.key), fit_on)
                preds = ctx.methods[name].predict(fitted, given.without_targets())
                pred = np.concatenate([np.asarray(p, dtype=float).reshape(len(s), -1)[:, col]
                                       for p, s in zip(preds, shown.segments)])
                weights = weights_of(ctx.methods[name], fitted, given.without_targets())
            except REFIT_ERRORS as exc:
                notes.append(f"{where}: re-fit failed ({type(exc).__name__}: {exc}); not drawn")
                continue
            flags = getattr(preds, "diverged", None)
            out.append(Predictions(target, window, split, name, part, repetition, time, truth, pred, segment,
                                   None if flags is None else np.asarray(flags, dtype=bool)[segment],
                                   None if weights is None else np.concatenate(weights)))
    return out, notes
