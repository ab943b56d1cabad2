"""Running experiments and reading their results from Python (a notebook, a script); re-exported by
``enginebench.api`` and ``enginebench``. docs/python.md walks through it.

``run(experiment, **overrides)`` runs an experiment (a built-in name, a TOML path, a dict or an
``ExperimentSpec``) into a run store and returns its ``Run``; ``open_run(ref)`` opens a stored run.
A ``Run`` gives pandas DataFrames: ``table()`` (the long summary ``enginebench table RUN --format
csv`` prints, with tidier column names), ``jobs()`` (one row per job: coordinates, status, reason,
picks, timings) and ``predictions(method, target)`` (the method re-fitted with the hyperparameters
its job selected, predicting an evaluated part).

Every mistake (an unknown experiment or override, a reference that finds no run, a reference of
the wrong type, a method the run did not run) is one ``EngineBenchError`` line; nothing here
answers a bad reference with a TypeError.

Nothing is computed twice: the table comes from ``results.summary``/``results.tables`` (the
CLI's), the picks from ``results.picks``, the predictions from ``reports.refit`` and
``reports.trajectories`` (the reports' re-fits), the run from ``experiments.runner``.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

from enginebench.errors import DataError, EngineBenchError, MethodError, SpecError, StoreError
from enginebench.results import store as _store

if TYPE_CHECKING:
    import pandas as pd

    from enginebench.experiments.spec import ExperimentSpec

__all__ = ["TABLE_COLUMNS", "Run", "open_run", "run"]

TABLE_COLUMNS = {"Delta [s]": "Delta", "ci_low": "low", "ci_high": "high", "n_repeats": "n"}
"""How ``Run.table`` renames the columns of ``enginebench table RUN --format csv`` (every other column, and
every value, is the csv's). ``Delta`` is the input window in seconds (``window`` in ``jobs()`` and the spec)."""

TIMING_PREFIX = "time:"
"""Prefix of ``Run.jobs``' timing columns (``time:fit_s``, ``time:select_s``, ``time:predict_test_s``...)."""


class Run(_store.Run):
    """One stored run (a run folder), with its results as pandas DataFrames.

    ``Run(path)`` takes a run folder (str or Path); ``open_run`` also takes an id, a unique id
    prefix or 'latest'. Everything of the store's run is here too (``id``, ``path``, ``info()``,
    ``config()``, ``metrics()``, ``job_metas()``, ``selection_table()``...).
    """

    def __post_init__(self) -> None:
        if not isinstance(self.path, (str, os.PathLike)):
            raise StoreError(f"a run is opened from its folder or id (str or Path), not {type(self.path).__name__} "
                             f"{_short(self.path)}; use enginebench.api.open_run(ref)")
        super().__post_init__()

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r})"

    # -- the comparison table ---------------------------------------------------------------
    def table(self, metrics: str | Sequence[str] | None = None, interval: str | None = None) -> "pd.DataFrame":
        """The run's long summary: one row per dataset, target, mode, Delta, method, split and metric, with
        mean, low and high (the interval over repetitions), sd, median, iqr, n (repetitions), n_failed,
        interval (its kind: t or bootstrap), n_diverged, n_segments and note.

        Value for value what ``enginebench table RUN --format csv`` prints, its columns renamed by
        ``TABLE_COLUMNS``. ``metrics`` keeps those metrics only (a name or a list; DataError on one the
        run lacks); ``interval`` ('t' or 'bootstrap') replaces the run's own.
        """
        from enginebench.results import tables
        from enginebench.results.units import run_units

        if interval is not None and interval not in ("t", "bootstrap"):
            raise DataError(f"interval {interval!r} is not one of t, bootstrap")
        raw = self.metrics()
        if len(raw) and not (raw["status"] == "ok").any():
            raise DataError(f"no job of run {self.id} succeeded, so there is no table; Run.jobs() gives each "
                            "job's reason")
        summary = tables.summarize(raw, interval=interval or self.config().get("interval", "t"))
        frame = tables.long_table(summary, units=run_units(self.info()))
        if metrics is not None:
            wanted = [metrics] if isinstance(metrics, str) else list(metrics)
            have = sorted(set(frame["metric"]))
            unknown = [m for m in wanted if m not in have]
            if unknown:
                raise DataError(f"metrics: unknown metric(s) {', '.join(map(str, unknown))}; run {self.id} has "
                                f"{', '.join(have)}")
            frame = frame[frame["metric"].isin(wanted)].reset_index(drop=True)
        return frame.rename(columns=TABLE_COLUMNS)

    # -- the jobs ----------------------------------------------------------------------------
    def jobs(self) -> "pd.DataFrame":
        """One row per stored job: method, target, window (seconds), split, repetition, job (its key),
        status, reason (why it failed; empty when ok), how (selected, fixed, none, failed), grid_size,
        resamples, score (the selected point's mean selection score), folds_stored, n_train, warnings
        (joined by '; '), one ``param:<name>`` column per selected hyperparameter and one ``time:<name>``
        column per timing the job recorded (fit_s, select_s, predict_<part>_s), then time:total_s.

        The picks are ``enginebench table RUN --picks --format csv``'s columns, row for row.
        """
        import pandas as pd

        from enginebench.results.picks import PARAM, picks_frame

        picks = picks_frame(self)
        metas = self.job_metas()
        extra = []
        for key in picks["job"]:
            meta = metas.get(key, {})
            timings = {f"{TIMING_PREFIX}{k}": float(v) for k, v in (meta.get("timings") or {}).items()
                       if isinstance(v, (int, float))}
            extra.append({"reason": "" if meta.get("status", "ok") == "ok" else str(meta.get("reason", "")),
                          "n_train": meta.get("n_train"),
                          "warnings": "; ".join(str(w) for w in meta.get("warnings") or []), **timings})
        extra_frame = pd.DataFrame(extra, index=picks.index, columns=_ordered(extra))
        if len(extra_frame.columns) > 3:
            timing_cols = [c for c in extra_frame.columns if c.startswith(TIMING_PREFIX)]
            extra_frame[f"{TIMING_PREFIX}total_s"] = extra_frame[timing_cols].sum(axis=1, min_count=1)
        extra_frame["n_train"] = extra_frame["n_train"].astype("Int64")
        params = [c for c in picks.columns if c.startswith(PARAM)]
        fixed = [c for c in picks.columns if c not in params]
        at = fixed.index("status") + 1
        out = pd.concat([picks[fixed[:at]], extra_frame[["reason"]], picks[fixed[at:]],
                         extra_frame[["n_train", "warnings"]], picks[params],
                         extra_frame[[c for c in extra_frame.columns if c.startswith(TIMING_PREFIX)]]], axis=1)
        return out

    # -- predictions -------------------------------------------------------------------------
    def predictions(self, method: str, target: str | None = None, *, window: float | None = None,
                    split: str | None = None, part: str = "test", repetition: int = 0,
                    max_rows: int | None = None) -> "pd.DataFrame":
        """``method`` re-fitted on repetition ``repetition``'s training rows with the hyperparameters its job
        selected, predicting ``part``: one row per predicted sample with target, window (seconds), split, method, part,
        repetition, segment (the record's id), time (seconds), truth, prediction and diverged (the free
        run left its envelope; simulation runs).

        Predictions are not stored in a run: they are computed again here (the data loaded, the model
        fitted), as the reports and ``enginebench plots`` do, with the job's own final-fit generator, so
        they are the job's own predictions, a random method's draws included (not where the job tested the
        selection's own model, ``refit = false``: that one is drawn afresh). ``target`` may be left out when the run has
        one; ``window`` and ``split`` narrow the rows (default: all of the run's). Static and window
        runs thin a part longer than ``max_rows`` (default 20,000) to evenly spaced rows.
        """
        import numpy as np
        import pandas as pd

        cfg = self.config()
        targets, ran = list(cfg.get("targets") or []), list(cfg.get("methods") or [])
        if method not in ran:
            raise MethodError(f"run {self.id} did not run method {method!r}; it ran {', '.join(ran)}")
        if target is None:
            if len(targets) != 1:
                raise DataError(f"run {self.id} has targets {', '.join(targets)}; name one: "
                                f"predictions({method!r}, target=...)")
            target = targets[0]
        elif target not in targets:
            raise DataError(f"run {self.id} has no target {target!r}; its targets are {', '.join(targets)}")
        if not isinstance(repetition, int) or not 0 <= repetition < int(cfg.get("repetitions", 1)):
            raise DataError(f"repetition {repetition!r} is not one of run {self.id}'s 0..{int(cfg.get('repetitions', 1)) - 1}")
        frames = []
        if cfg.get("mode") == "simulation":
            from enginebench.reports.trajectories import simulate_run

            sims, notes = simulate_run(self, methods=[method], trajectories=2**31, part=part, repetition=repetition)
            for sim in sims:
                if sim.target != target or method not in sim.sims:
                    continue
                flags = sim.diverged.get(method, np.zeros(len(sim.time), dtype=bool))
                for k, seg in enumerate(sim.segment_ids):
                    frames.append(pd.DataFrame({
                        "target": sim.target, "window": float(sim.window), "split": sim.split, "method": method,
                        "part": part, "repetition": repetition, "segment": str(seg), "time": sim.time[k],
                        "truth": sim.truth[k], "prediction": sim.sims[method][k], "diverged": bool(flags[k])}))
        else:
            from enginebench.reports.refit import MAX_ROWS, refit_predictions

            preds, notes = refit_predictions(self, repetition=repetition, part=part, methods=[method],
                                             max_rows=MAX_ROWS if max_rows is None else max_rows)
            for p in preds:
                if p.target != target:
                    continue
                frames.append(pd.DataFrame({
                    "target": p.target, "window": float(p.window), "split": p.split, "method": p.method,
                    "part": p.part, "repetition": p.repetition, "segment": p.segment.astype(str),
                    "time": p.time, "truth": p.truth, "prediction": p.pred,
                    "diverged": np.zeros(len(p.time), dtype=bool) if p.diverged is None else p.diverged}))
        for note in notes:
            warnings.warn(note, stacklevel=2)
        out = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(
            columns=["target", "window", "split", "method", "part", "repetition", "segment", "time", "truth",
                     "prediction", "diverged"])
        if window is not None:
            out = out[np.isclose(out["window"].astype(float), float(window))]
        if split is not None:
            out = out[out["split"] == split]
        if out.empty:
            why = "; ".join(notes) if notes else "no rows match the window and split asked for"
            raise MethodError(f"run {self.id}: no predictions of {method} for {target} ({why})")
        return out.reset_index(drop=True)


def _ordered(rows: list[dict[str, Any]]) -> list[str]:
    """Column names of ``rows`` in first-seen order."""
    seen: dict[str, None] = {}
    for row in rows:
        seen.update(dict.fromkeys(row))
    for name in ("reason", "n_train", "warnings"):
        seen.setdefault(name)
    return list(seen)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def open_run(ref: str | os.PathLike[str] | _store.Run, store: str | os.PathLike[str] | None = None) -> Run:
    """A stored run: a run folder (a Path, or a string naming an existing folder), or a run id, a unique id
    prefix or 'latest' in ``store`` (default: $ENGINEBENCH_STORE, else ./enginebench-runs); a ``Run`` is
    returned as this module's ``Run``. Anything that finds no run, a reference of another type included,
    is one StoreError line saying what to give."""
    if isinstance(ref, _store.Run):
        return Run(ref.path)
    if not isinstance(ref, (str, os.PathLike)):
        raise StoreError(f"open_run takes a run id or a run folder (str or Path), not {type(ref).__name__} "
                         f"{_short(ref)}")
    if store is not None and not isinstance(store, (str, os.PathLike)):
        raise StoreError(f"store must be a folder (str or Path), not {type(store).__name__} {_short(store)}")
    if not str(os.fspath(ref)).strip():
        raise StoreError("an empty run reference; give a run id, a unique id prefix, 'latest' or a run folder")
    return Run(_store.open_run(ref, store).path)


def _spec_of(experiment: Any) -> "ExperimentSpec":
    from enginebench.experiments.spec import ExperimentSpec, from_dict, load_spec

    if isinstance(experiment, ExperimentSpec):
        return experiment
    if isinstance(experiment, Mapping):
        raw = dict(experiment)
        raw.setdefault("name", "experiment")
        return from_dict(raw, origin="the experiment dict")
    if isinstance(experiment, (str, os.PathLike)):
        return load_spec(os.fspath(experiment) if isinstance(experiment, os.PathLike) else experiment)
    raise SpecError(f"an experiment is a built-in name, a .toml path, a dict or an ExperimentSpec, not "
                    f"{type(experiment).__name__} {_short(experiment)}")


def _with_overrides(spec: "ExperimentSpec", overrides: dict[str, Any]) -> "ExperimentSpec":
    """``spec`` with top-level keys replaced. ``methods`` as a list keeps the options the spec gave those
    methods; as a dict (name -> options) it replaces methods and options. Unknown keys are one SpecError."""
    from dataclasses import asdict

    from enginebench.experiments.spec import from_dict

    if not overrides:
        return spec
    d = spec.to_dict()
    changes = dict(overrides)
    methods = changes.pop("methods", None)
    if isinstance(methods, str):
        methods = [methods]
    if isinstance(methods, Mapping):
        d["methods"], d["method_options"] = list(methods), {k: dict(v or {}) for k, v in methods.items()}
    elif methods is not None:
        d["methods"] = methods
        if isinstance(methods, list):
            d["method_options"] = {k: v for k, v in spec.method_options.items() if k in methods}
    d.update(changes)
    if not isinstance(d.get("selection"), dict) and hasattr(d.get("selection"), "__dataclass_fields__"):
        d["selection"] = asdict(d["selection"])
    return from_dict(d, origin=f"run() overrides ({', '.join(overrides)})")


def _refuse_in_worker_import() -> None:
    """Refuse a run started while a spawned worker process imports the user's script.

    Worker processes start by importing the ``__main__`` script (the "spawn" start method); an
    unguarded ``run(...)`` at the top of that script would start a run of its own in every worker,
    each leaving an unfinished run in the store. multiprocessing marks a process still importing
    its parent's main module with ``_inheriting`` (its own check for this case reads the same flag).
    """
    import multiprocessing

    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise EngineBenchError(
            "enginebench.api.run was called while a worker process imported your script: put the call under "
            "`if __name__ == \"__main__\":` (worker processes import the script to start), or pass workers=1")


def run(
    experiment: "str | os.PathLike[str] | Mapping[str, Any] | ExperimentSpec",
    *,
    workers: int | None = None,
    store: str | os.PathLike[str] | None = None,
    tags: Mapping[str, str] | None = None,
    progress: bool | Callable[[int, int, Any], None] = False,
    executor: str = "local",
    scheduler: str | None = None,
    plugins: Sequence[str | os.PathLike[str]] = (),
    **overrides: Any,
) -> Run:
    """Run ``experiment`` and return the stored run.

    ``experiment`` is a built-in name (``enginebench experiments`` lists them), a .toml path, a dict of
    the TOML's keys, or an ``ExperimentSpec``. ``overrides`` replace top-level keys of the experiment
    (``repetitions=2``, ``methods=["naive-mean", "ridge"]``, ``windows=[0]``, ``targets=[...]``,
    ``train_size=200``, ``selection={...}``...). ``workers``: worker processes (default: all cores);
    ``store``: the run store folder (default: $ENGINEBENCH_STORE, else ./enginebench-runs); ``tags``:
    KEY -> VALUE labels kept in run.json; ``progress``: True for a progress bar (on stderr), or a
    callable ``(done, total, job)``; ``executor`` / ``scheduler``: as ``enginebench run --executor``
    / ``--scheduler``; ``plugins``: plugin files defining more methods.

    Every finished job is stored at once, as with ``enginebench run``: an interrupted run keeps what
    it finished, and ``enginebench run --resume RUN`` finishes it.
    """
    from enginebench.experiments.executors import WorkerDied
    from enginebench.experiments.runner import run_experiment
    from enginebench.registry import load_plugin_file
    from enginebench.results.catalog import check_tags

    _refuse_in_worker_import()
    spec = _with_overrides(_spec_of(experiment), overrides)
    if tags is not None and not isinstance(tags, Mapping):
        raise SpecError(f"tags must be a dict of KEY -> VALUE, not {type(tags).__name__} {_short(tags)}")
    tag_map = {str(k): str(v) for k, v in (tags or {}).items()}
    if tag_map:
        check_tags(tag_map)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)):
        raise SpecError(f"workers must be a whole number >= 1, not {_short(workers)}")
    paths = tuple(str(Path(p).resolve()) for p in plugins)
    for path in paths:
        load_plugin_file(path)
    store_obj = _store.RunStore(store)
    options = dict(workers=workers, plugins=paths, executor=executor, scheduler=scheduler, tags=tag_map)
    try:
        result = _run_with_progress(run_experiment, spec, store_obj, progress, options)
    except WorkerDied as exc:
        raise WorkerDied(f"{exc}. From a Python script, call enginebench.api.run under "
                         "`if __name__ == \"__main__\":` (each worker process imports the script), or pass workers=1"
                         ) from exc.__cause__
    return Run(result.run.path)


def _run_with_progress(run_experiment: Callable[..., Any], spec: ExperimentSpec, store_obj: Any,
                       progress: bool | Callable[[int, int, Any], None], options: dict[str, Any]) -> Any:
    """run_experiment with ``progress`` as api.run takes it: a callable, a bar on stderr (True), or nothing."""
    if callable(progress):
        return run_experiment(spec, store_obj, progress=progress, **options)
    if not progress:
        return run_experiment(spec, store_obj, **options)
    from enginebench.cli.progress import JobProgress

    name = spec.name
    with JobProgress(f"{name}: preparing", lambda job: f"{name}: last done {job.method} r{job.repetition}", False,
                     running=f"{name}: running",
                     running_label=lambda job: f"{name}: running {job.method} {job.target} r{job.repetition}"
                     ) as bar:
        result = run_experiment(spec, store_obj, progress=bar, **options)
        bar.describe(f"{name}: done")
    return result
