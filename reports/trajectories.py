"""Trajectory figures for a stored simulation run: re-fit its methods for one repetition and draw them.

For each (target, window, split) of the run, every chosen method is fitted again on
that repetition's training trajectories with the hyperparameters the run selected
(read from the stored job), and a few trajectories of the evaluated part are drawn as in
the turboshaft-moe paper's Figs. 3-6: all methods against the truth (scaled by mean |y| over training),
the run-time inputs, and the mixing weights of the first method that declares them
(``Method.explain``'s ``"weights"``: a mixture of experts' gate, a cascade's downstream
gate, evaluated along the simulated trajectory) as stacked bands.
One measured-vs-predicted scatter per method is written too.

The re-fit draws its random numbers from the job's own final-fit generator
(``jobs.final_fit_rng``), so it is the job's model, a random method's (narx's centres, MoE's
weights) included; the figure says "re-fitted".
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from enginebench.errors import EngineBenchError, MethodError
from enginebench.experiments.jobs import JOINT, Context, job_for, refit_stored_job, training_samples
from enginebench.experiments.recorded_options import with_recorded_options
from enginebench.experiments.runner import prepare
from enginebench.experiments.spec import ExperimentSpec, from_dict
from enginebench.method import EXPLAIN_WEIGHTS, Method
from enginebench.reports.plots import scatter_plot, trajectory_plot
from enginebench.results.run_folder import Run
from enginebench.results.units import run_units


@dataclass
class PlotReport:
    """What was written, and what was skipped with the reason."""

    paths: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    bands: dict[Path, str] = field(default_factory=dict)
    """Trajectory figure -> the method whose mixing weights are drawn as bands under it."""
    simulated: list["Simulated"] = field(default_factory=list)
    """The arrays drawn (``simulate_run``), for other views of the same re-fit."""


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-")


def weights_of(method: Method, fitted: Any, data) -> list[np.ndarray] | None:
    """The method's mixing weights per segment of ``data`` (its ``explain`` hook's ``"weights"``), or None.

    Declared by the method (a mixture of experts: its gate; a cascade: its downstream's),
    never recognised here by name or class.
    """
    weights = method.explain(fitted, data).get(EXPLAIN_WEIGHTS)
    return None if weights is None else [np.asarray(w, dtype=float) for w in weights]


@dataclass
class Simulated:
    """One (target, window, split)'s re-fitted simulations of the trajectories shown, as arrays.

    Lists run over the shown segments (in the part's order); ``sims`` and ``diverged``
    hold only the methods that were re-fitted without error.
    """

    target: str
    window: float
    split: str
    part: str
    repetition: int
    scale: float
    """mean |y| over the repetition's training rows."""
    segment_ids: list[str]
    time: list[np.ndarray]
    """Time stamps (seconds, the dataset's time axis) per shown segment."""
    truth: list[np.ndarray]
    inputs: list[dict[str, np.ndarray]]
    sims: dict[str, list[np.ndarray]] = field(default_factory=dict)
    diverged: dict[str, np.ndarray] = field(default_factory=dict)
    """Method -> one flag per shown segment (a simulation that left its envelope)."""
    gate: list[np.ndarray] | None = None
    gate_label: str = ""
    """The method whose ``explain`` weights ``gate`` holds ('' when none declares them)."""
    train_inputs: dict[str, np.ndarray] = field(default_factory=dict)
    """The first inputs over the repetition's training rows (for the operating map)."""


def prepared(run: Run, spec: ExperimentSpec, methods: Sequence[str] | None) -> tuple[Context, list[str]]:
    """A stored run's context prepared again, and the methods to re-fit: ``methods``, or all the run ran
    (MethodError naming one it did not run). Both re-fits of the reports start here. The methods carry the
    options the run recorded (``runner.with_recorded_options``), so a default changed since does not change
    the model re-fitted."""
    ctx = with_recorded_options(prepare(spec), run)
    chosen = list(methods) if methods else list(spec.methods)
    unknown = [m for m in chosen if m not in ctx.methods]
    if unknown:
        raise MethodError(f"run {run.id} did not run method(s) {', '.join(unknown)}; it ran {', '.join(ctx.methods)}")
    return ctx, chosen


def simulate_run(
    run: Run,
    methods: list[str] | None = None,
    trajectories: int = 3,
    part: str = "test",
    repetition: int = 0,
    max_inputs: int = 3,
) -> tuple[list[Simulated], list[str]]:
    """Re-fit ``run``'s methods for one repetition and simulate the ``trajectories`` longest of ``part``.

    Returns one ``Simulated`` per (target, window, split) with at least one method drawn,
    and notes on the methods whose re-fit failed.
    """
    spec = from_dict(run.config(), origin=f"run {run.id}")
    if spec.mode != "simulation":
        raise MethodError(f"run {run.id} is in mode {spec.mode!r}; trajectory plots are for simulation runs")
    ctx, chosen = prepared(run, spec, methods)
    if trajectories < 1:
        raise MethodError(f"trajectories must be >= 1, got {trajectories}")
    out: list[Simulated] = []
    notes: list[str] = []
    for (target, window, split), problem in ctx.problems.items():
        if target == JOINT:  # drawn target by target below
            continue
        if part not in problem.parts:
            raise MethodError(f"run {run.id}: split {split!r} has no {part!r} part; it has {', '.join(problem.parts)}")
        train = training_samples(spec, problem, repetition, split)
        data = problem.parts[part].materialize()
        order = np.argsort([-len(s) for s in data.segments], kind="stable")[:trajectories]
        rows = np.concatenate([_segment_rows(data, int(k)) for k in sorted(order)])
        shown = data.take(rows)
        sim = Simulated(target, window, split, part, repetition, float(np.mean(np.abs(train.y))),
                        [s.id for s in shown.segments], [s.t[s.rows] for s in shown.segments],
                        [s.y[:, 0] for s in shown.segments],
                        [{c: s.U[s.rows, j] for j, c in enumerate(shown.input_names[:max_inputs])}
                         for s in shown.segments],
                        train_inputs={c: np.concatenate([s.U[s.rows, j] for s in train.segments])
                                      for j, c in enumerate(train.input_names[:2])})
        for name in chosen:
            job, own, col = job_for(ctx, target, window, split, name, repetition)
            method = ctx.methods[name]
            fit_on, given = (train, shown) if own is problem else (
                training_samples(spec, own, repetition, split), own.parts[part].materialize().take(rows))
            try:
                fitted = refit_stored_job(ctx, job, run.job_meta(job.key), fit_on)
                preds = method.predict(fitted, given.without_targets())
                if sim.gate is None:
                    sim.gate = weights_of(method, fitted, given.without_targets())
                    sim.gate_label = name if sim.gate is not None else ""
            except (EngineBenchError, ValueError, RuntimeError, FloatingPointError) as exc:
                notes.append(f"{name}: not drawn ({type(exc).__name__}: {exc})")
                continue
            sim.sims[name] = [np.asarray(p, dtype=float).reshape(len(s), -1)[:, col]
                              for p, s in zip(preds, shown.segments)]
            sim.diverged[name] = np.asarray(getattr(preds, "diverged", np.zeros(len(preds), dtype=bool)), dtype=bool)
        if sim.sims:
            out.append(sim)
    return out, notes


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
    simulated, notes = simulate_run(run, methods, trajectories, part, repetition, max_inputs)
    units = run_units(run.info())  # {} for a run made before units were recorded: labels without units
    out = Path(out_dir)
    report = PlotReport(notes=notes, simulated=simulated)
    for sim in simulated:
        target, window, gate, gate_label = sim.target, sim.window, sim.gate, sim.gate_label
        for k, seg_id in enumerate(sim.segment_ids):
            title = (f"{target} on {part} trajectory {seg_id}" + (f"; gate bands: {gate_label}" if gate_label else "")
                     + f"\nrun {run.id}, repetition {repetition}, re-fitted")
            path = out / f"{_safe(target)}__w{window:g}__{_safe(seg_id)}.png"
            report.paths.append(trajectory_plot(
                sim.time[k] - sim.time[k][0], sim.truth[k], {m: v[k] for m, v in sim.sims.items()},
                None if gate is None else gate[k], path, inputs=sim.inputs[k], scale=sim.scale, title=title,
                ylabel=target, unit=units.get(target, ""), input_units=units,
            ))
            if gate_label:
                report.bands[report.paths[-1]] = gate_label
        for name, values in sim.sims.items():
            path = out / f"{_safe(target)}__w{window:g}__scatter__{_safe(name)}.png"
            report.paths.append(scatter_plot(
                np.concatenate(sim.truth), np.concatenate(values), path,
                title=f"{name}: {target}, {part} trajectories shown (run {run.id})", label=target,
                unit=units.get(target, ""),
            ))
    return report


def _segment_rows(data, k: int) -> np.ndarray:
    start = sum(len(s) for s in data.segments[:k])
    return np.arange(start, start + len(data.segments[k]))
