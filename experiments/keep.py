"""What a job keeps of its tested model after the test: the stored model and the real-time figures.

``after_test`` runs at the end of a successful job (``experiments/jobs.py``):

* with ``[store] models = true`` (``run --keep-models``) the fitted model is encoded as a stored model
  (``results/model_store.py``) with the test part and the job's predictions of it; ``Run.write_job``
  writes it as ``models/<job-key>.npz``. A model that cannot be stored leaves the job as it is, with a
  warning saying why.
* in simulation mode, the time of one model step over the whole test part: a method timing its own step
  (``Method.step_times``; the built-in methods with a C step compile it with gcc and time each step in C)
  gives median, p99, worst, and the real-time factor dt / worst (``source = "c-step"``); otherwise, or
  without a compiler, the job's own prediction time over the test part's steps (``source =
  "python-batched"``, median = p99 = worst = the mean, since a batched free run times no single step). The figures go into the job's metadata
  (``realtime``) and its metric rows (``rt_median_us``, ``rt_p99_us``, ``rt_worst_us``, ``rt_factor``;
  ``table --metrics rt``). Timing is measured and reported, never asserted.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from enginebench.errors import EngineBenchError, MethodError
from enginebench.results.model_store import MODEL_META, encode_model
from enginebench.results.realtime import RT_METRICS, step_figures


def realtime_figures(method: Any, fitted: Any, test: Any, predict_s: float | None) -> dict[str, Any]:
    """One step's time over the whole test part ``test`` (``Samples``) as ``step_figures`` gives it: the method's
    own step timed by its ``step_times`` hook, else the job's prediction time over the steps."""
    why = "the method times no step of its own"
    try:
        timed = method.step_times(fitted, test)
    except MethodError as exc:  # e.g. no C compiler on this machine
        timed, why = None, str(exc)
    if timed is not None:
        source, times = timed
        return step_figures(np.asarray(times, dtype=np.float64), test.dt, source)
    steps = sum(len(s.t) for s in test.segments)
    mean = (predict_s or float("nan")) / max(steps, 1)
    out = step_figures(np.full(1, mean), test.dt, "python-batched")
    out.update(steps=steps, note=f"the test part's prediction time over its {steps} steps ({why})")
    return out


def after_test(spec: Any, job: Any, method: Any, fitted: Any, problem: Any, params: dict[str, Any],
               meta: dict[str, Any], predicted: dict[str, list[np.ndarray]], timings: dict[str, float]
               ) -> list[dict[str, Any]]:
    """Store the model (when asked) and measure the real-time figures (simulation mode): fills ``meta``,
    returns the real-time metric rows to add (``{"target", "metric", "value"}``, split test)."""
    rows: list[dict[str, Any]] = []
    test_part = problem.parts.get("test")
    if test_part is None:
        return rows
    test = test_part.materialize() if spec.mode == "simulation" else None
    if spec.mode == "simulation":
        try:
            figures = realtime_figures(method, fitted, test, timings.get("predict_test_s"))
            meta["realtime"] = figures
            for name in test.target_names:  # rt_median_us <- median_us ... rt_factor <- rt_factor
                rows += [{"target": name, "metric": m, "value": figures[m if m == "rt_factor" else m[3:]]}
                         for m in RT_METRICS]
        except (EngineBenchError, OSError) as exc:
            meta.setdefault("warnings", []).append(f"{job.method}: real-time figures not measured ({exc})")
    if getattr(spec, "store_models", False):
        try:
            if test is None:  # static and window modes: the first block of rows the job predicted
                test = next(iter(test_part.batches(20_000, method.uses_features)))
            preds = predicted.get("test", [])
            check = (test.without_targets(), _cut(preds, test)) if test is not None else None
            meta[MODEL_META] = encode_model(
                method, fitted, data=test, params=params,
                job={"key": job.key, "target": job.target, "window": job.window, "split": job.split,
                     "method": job.method, "repetition": job.repetition, "dataset": meta.get("dataset")},
                check=check)
        except EngineBenchError as exc:
            meta.setdefault("warnings", []).append(f"{job.method}: model not stored ({exc})")
    return rows


def _cut(preds: list[np.ndarray], test: Any) -> list[np.ndarray]:
    """The job's test predictions for the segments of ``test`` (all of them, or the first block's rows)."""
    flat = np.concatenate(preds) if preds else np.empty((0, len(test.target_names)))
    sizes = [len(s) for s in test.segments]
    return np.split(flat[:sum(sizes)], np.cumsum(sizes)[:-1]) if sizes else []
