"""One job of a run: (target, window, split, method, repetition) -> metric rows.

A job is deterministic given the experiment and its coordinates: the training subsample
depends only on (seed, repetition, split), so every method of a repetition sees the same
rows and the methods can be compared pairwise; the method's own draws depend on
(seed, repetition, method).
"""

from __future__ import annotations

import time
import traceback
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from enginebench.datasets.samples import Samples
from enginebench.errors import EngineBenchError
from enginebench.experiments.selection import select
from enginebench.experiments.spec import ExperimentSpec
from enginebench.methods.base import Method
from enginebench.results.metrics import compute_metrics


@dataclass(frozen=True)
class Job:
    target: str
    window: float
    split: str
    method: str
    repetition: int

    @property
    def key(self) -> str:
        safe = lambda s: "".join(ch if ch.isalnum() or ch in "-._" else "-" for ch in s)  # noqa: E731
        return f"{safe(self.target)}__w{self.window:g}__{safe(self.split)}__{safe(self.method)}__r{self.repetition:03d}"


@dataclass(frozen=True)
class Problem:
    """The samples of one (target, window, split): the training pool and the evaluated parts."""

    train: Samples
    parts: dict[str, Samples]


@dataclass
class Context:
    """Everything a worker needs, prepared once in the parent."""

    spec: ExperimentSpec
    dataset: str
    problems: dict[tuple[str, float, str], Problem]
    methods: dict[str, Method]
    dataset_hash: str = ""


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


def run_job(ctx: Context, job: Job) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Run one job; failures become a 'failed' record with the reason, never an exception."""
    spec = ctx.spec
    problem = ctx.problems[(job.target, job.window, job.split)]
    method = ctx.methods[job.method]
    base = {"dataset": ctx.dataset, "target": job.target, "mode": spec.mode, "window": job.window,
            "method": job.method, "family": method.family, "repetition": job.repetition}
    meta: dict[str, Any] = {"job": job.key, **base}
    timings: dict[str, float] = {}
    rows: list[dict[str, Any]] = []
    try:
        sub_rng = np.random.default_rng([spec.seed, job.repetition, stable_int(job.split)])
        if spec.mode == "simulation":  # a trajectory is only usable whole
            sizes = np.array([len(s) for s in problem.train.segments])
            train = problem.train.take(subsample_segments(sizes, spec.train_size, sub_rng))
        else:
            train = problem.train.take(subsample(len(problem.train), spec.train_size, sub_rng))
        rng = np.random.default_rng([spec.seed, job.repetition, stable_int(job.method)])
        t0 = time.perf_counter()
        params, search = select(method, train, spec.selection, rng, problem.parts.get("validation"))
        timings["select_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        fitted = method.fit(train, params, rng)
        timings["fit_s"] = time.perf_counter() - t0
        y_train = train.y
        scale = float(np.mean(np.abs(y_train)))
        meta.update(params=params, search=search, describe=method.describe(fitted), n_train=len(train))
        for part_name, part in problem.parts.items():
            t0 = time.perf_counter()
            preds = method.predict(fitted, part.without_targets())
            timings[f"predict_{part_name}_s"] = time.perf_counter() - t0
            diverged = np.asarray(getattr(preds, "diverged", np.zeros(len(preds), bool)))
            for k, name in enumerate(part.target_names):
                truth = [s.y[:, k] for s in part.segments]
                guess = [np.asarray(p, dtype=float).reshape(len(s), -1)[:, k] for p, s in zip(preds, part.segments)]
                bad = [s.id for s, g in zip(part.segments, guess) if not np.all(np.isfinite(g))]
                if bad:
                    raise FloatingPointError(
                        f"{job.method} returned non-finite predictions for {len(bad)} segment(s) of the {part_name} part "
                        f"(first: {bad[0]})"
                    )
                values, notes = compute_metrics(truth, guess, scale)
                values["diverged"] = float(diverged.sum())
                for metric, value in values.items():
                    rows.append({**base, "target": name, "split": part_name, "metric": metric, "value": float(value)})
                if notes:
                    meta.setdefault("notes", {}).update({f"{part_name}:{k}": v for k, v in notes.items()})
        meta["status"] = "ok"
    except (EngineBenchError, FloatingPointError, np.linalg.LinAlgError, ValueError, RuntimeError) as exc:
        rows = []
        meta.update(status="failed", reason=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(limit=5))
    meta["timings"] = timings
    if not rows:
        rows.append({**base, "split": "-", "metric": "failed", "value": float("nan")})
    for name, value in timings.items():
        rows.append({**base, "split": "-", "metric": f"time_{name}", "value": value})
    frame = pd.DataFrame(rows)
    frame["status"] = meta["status"]
    return frame, meta
