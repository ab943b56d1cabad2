"""Trajectory figures for a stored simulation run: re-fit its methods for one repetition and draw them.

For each (target, window, split) of the run, every chosen method is fitted again on
that repetition's training trajectories with the hyperparameters the run selected
(read from the stored job), and a few trajectories of the evaluated part are drawn as in
seed 003's Figs. 3-6: all methods against the truth (scaled by mean |y| over training),
the run-time inputs, and the mixing weights of the first method that declares them
(``Method.explain``'s ``"weights"``: a mixture of experts' gate, a cascade's downstream
gate, evaluated along the simulated trajectory) as stacked bands.
One measured-vs-predicted scatter per method is written too.

The re-fit draws its random numbers from a generator seeded like the run's job but
without replaying the model selection, so a stochastic method (MoE) may differ slightly
from the stored job; the figure says "re-fitted".
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from enginebench.errors import EngineBenchError, MethodError
from enginebench.experiments.jobs import Job, refit_stored_job, training_samples
from enginebench.experiments.runner import prepare
from enginebench.experiments.spec import from_dict
from enginebench.methods.base import EXPLAIN_WEIGHTS, Method
from enginebench.results.plots import scatter_plot, trajectory_plot
from enginebench.results.store import Run


@dataclass
class PlotReport:
    """What was written, and what was skipped with the reason."""

    paths: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    bands: dict[Path, str] = field(default_factory=dict)
    """Trajectory figure -> the method whose mixing weights are drawn as bands under it."""


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-")


def weights_of(method: Method, fitted: Any, data) -> list[np.ndarray] | None:
    """The method's mixing weights per segment of ``data`` (its ``explain`` hook's ``"weights"``), or None.

    Declared by the method (a mixture of experts: its gate; a cascade: its downstream's),
    never recognised here by name or class.
    """
    weights = method.explain(fitted, data).get(EXPLAIN_WEIGHTS)
    return None if weights is None else [np.asarray(w, dtype=float) for w in weights]


def plot_run(
    run: Run,
    out_dir: str | Path,
    methods: list[str] | None = None,
    trajectories: int = 3,
    part: str = "test",
    repetition: int = 0,
    max_inputs: int = 3,
) -> PlotReport:
    """Write trajectory and scatter PNGs of ``run`` into ``out_dir``; returns the paths and notes."""
    spec = from_dict(run.config(), origin=f"run {run.id}")
    if spec.mode != "simulation":
        raise MethodError(f"run {run.id} is in mode {spec.mode!r}; trajectory plots are for simulation runs")
    ctx = prepare(spec)
    chosen = methods or list(spec.methods)
    unknown = [m for m in chosen if m not in ctx.methods]
    if unknown:
        raise MethodError(f"run {run.id} did not run method(s) {', '.join(unknown)}; it ran {', '.join(ctx.methods)}")
    if trajectories < 1:
        raise MethodError(f"trajectories must be >= 1, got {trajectories}")
    out = Path(out_dir)
    report = PlotReport()
    for (target, window, split), problem in ctx.problems.items():
        if part not in problem.parts:
            raise MethodError(f"run {run.id}: split {split!r} has no {part!r} part; it has {', '.join(problem.parts)}")
        train = training_samples(spec, problem, repetition, split)
        scale = float(np.mean(np.abs(train.y)))
        data = problem.parts[part].materialize()
        order = np.argsort([-len(s) for s in data.segments], kind="stable")[:trajectories]
        shown = data.take(np.concatenate([_segment_rows(data, int(k)) for k in sorted(order)]))
        sims: dict[str, list[np.ndarray]] = {}
        gate: list[np.ndarray] | None = None
        gate_label = ""
        for name in chosen:
            job = Job(target, window, split, name, repetition)
            method = ctx.methods[name]
            try:
                fitted = refit_stored_job(ctx, job, run.job_meta(job.key), train)
                preds = method.predict(fitted, shown.without_targets())
                if gate is None:
                    gate = weights_of(method, fitted, shown.without_targets())
                    gate_label = name if gate is not None else ""
            except (EngineBenchError, ValueError, RuntimeError, FloatingPointError) as exc:
                report.notes.append(f"{name}: not drawn ({type(exc).__name__}: {exc})")
                continue
            sims[name] = [np.asarray(p, dtype=float).reshape(len(s), -1)[:, 0] for p, s in zip(preds, shown.segments)]
        if not sims:
            continue
        for k, seg in enumerate(shown.segments):
            inputs = {c: seg.U[seg.rows, j] for j, c in enumerate(shown.input_names[:max_inputs])}
            title = (f"{target} on {part} trajectory {seg.id}" + (f"; gate bands: {gate_label}" if gate_label else "")
                     + f"\nrun {run.id}, repetition {repetition}, re-fitted")
            path = out / f"{_safe(target)}__w{window:g}__{_safe(seg.id)}.png"
            report.paths.append(trajectory_plot(
                seg.t[seg.rows] - seg.t[seg.rows][0], seg.y[:, 0], {m: v[k] for m, v in sims.items()},
                None if gate is None else gate[k], path, inputs=inputs, scale=scale, title=title, ylabel=target,
            ))
            if gate_label:
                report.bands[report.paths[-1]] = gate_label
        for name, values in sims.items():
            path = out / f"{_safe(target)}__w{window:g}__scatter__{_safe(name)}.png"
            report.paths.append(scatter_plot(
                np.concatenate([s.y[:, 0] for s in shown.segments]), np.concatenate(values), path,
                title=f"{name}: {target}, {part} trajectories shown (run {run.id})", label=target,
            ))
    return report


def _segment_rows(data, k: int) -> np.ndarray:
    start = sum(len(s) for s in data.segments[:k])
    return np.arange(start, start + len(data.segments[k]))
