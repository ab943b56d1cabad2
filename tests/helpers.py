"""Helpers shared by test modules (importable as ``helpers``: pytest puts tests/ on the path)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import scipy.signal

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.pools import RawSegments, SamplePool, make_samples
from enginebench.datasets.schema import Column, Schema
from enginebench.experiments.spec import ExperimentSpec, from_dict
from enginebench.samples import Samples


def make_toy(n_segments: int = 4, n: int = 120, seed: int = 0, dt: float = 1.0) -> Dataset:
    """Segments of y = sin(u1) + 0.5 u2 + 0.2 y(t-1) + noise, one 'unit' group per segment."""
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(n_segments):
        u1 = rng.uniform(-2, 2, n)
        u2 = np.cumsum(rng.normal(0, 0.3, n))
        y = np.zeros(n)
        for i in range(n):
            y[i] = np.sin(u1[i]) + 0.5 * u2[i] + (0.2 * y[i - 1] if i else 0.0) + rng.normal(0, 0.01)
        parts.append(pd.DataFrame({
            SEGMENT: f"s{k}", TIME: (k * (n + 10) + np.arange(n)) * dt,
            "u1": u1, "u2": u2, "y": y + 10.0, "unit": f"g{k % 2}",
        }))
    frame = pd.concat(parts, ignore_index=True)
    schema = Schema((Column("u1", "input", "V"), Column("u2", "input", "bar"),
                     Column("y", "output", "degC"), Column("unit", "group")))
    ids = [f"s{k}" for k in range(n_segments)]
    meta = {"provenance": "test fixture", "licence": "CC0",
            "published_split": {"train": ids[:-1], "test": ids[-1:]}}
    return Dataset("toy", frame, schema, dt, meta)


def toy_spec(dataset: str | Path, **changes) -> ExperimentSpec:
    """A small experiment on the toy dataset file: naive mean and a 3 x 3 KRLS grid, 3 repetitions."""
    raw = {
        "name": "toy-exp", "dataset": str(dataset), "targets": ["y"], "repetitions": 3, "seed": 7,
        "train_size": 150, "selection": {"kind": "bootstrap", "resamples": 2},
        "methods": {"naive-mean": {}, "krls": {"gamma_grid": [-2, 0, 3], "lambda_grid": [-3, -1, 3]}},
    }
    raw.update(changes)
    return from_dict(raw, origin="test")


def interrupt_after(spec, store, jobs: int = 2, **options):
    """Run ``spec`` into ``store`` and stop it by an exception once ``jobs`` jobs are written; the interrupted Run."""
    import pytest

    from enginebench.experiments.runner import run_experiment

    class Stop(Exception):
        pass

    def stop(done, total, job):
        if done == jobs:
            raise Stop

    with pytest.raises(Stop):
        run_experiment(spec, store, progress=stop, **options)
    return store.runs()[-1]


def thread_limits_after_worker_setup(threads: int) -> list[tuple[str, int]]:
    """(library, threads) of every BLAS/OpenMP pool and torch after a worker's thread limit (run in a fresh process)."""
    import torch
    from threadpoolctl import threadpool_info

    from enginebench.experiments.executor_base import limit_threads

    limit_threads(threads)
    return [(info["filepath"], info["num_threads"]) for info in threadpool_info()] + [("torch", torch.get_num_threads())]


# -- a noise-free linear ARX system (tests of arx, narx, the peers) --
A_TRUE = np.array([1.0, -1.5, 0.7])          # A(q) = 1 - 1.5 q^-1 + 0.7 q^-2, poles 0.75 +- 0.37j
B1_TRUE = np.array([0.0, 0.5, 0.3])          # q^-1 (0.5 + 0.3 q^-1)
B2_TRUE = np.array([0.0, -0.2, 0.1])
OFFSET = 0.4


def linear_raw(n_seg: int = 3, n: int = 300, seed: int = 0) -> RawSegments:
    """Segments of A(q) y = B1(q) u1 + B2(q) u2 + OFFSET started at rest, noise-free."""
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n_seg):
        u1, u2 = rng.normal(size=n), rng.uniform(-1, 1, n)
        y = scipy.signal.lfilter(B1_TRUE, A_TRUE, u1) + scipy.signal.lfilter(B2_TRUE, A_TRUE, u2) \
            + scipy.signal.lfilter([OFFSET], A_TRUE, np.ones(n))
        frames.append(pd.DataFrame({"segment": f"s{k}", "time": np.arange(n) + 1000.0 * k, "u1": u1, "u2": u2, "y": y}))
    ds = Dataset("linear", pd.concat(frames, ignore_index=True),
                 Schema.from_roles({"u1": "input", "u2": "input", "y": "output"}), 1.0)
    return RawSegments.from_dataset(ds)


def sim_samples(raw: RawSegments, init_samples: int = 0) -> Samples:
    return SamplePool(raw, ["y"], "simulation", init_samples=init_samples).materialize()


def stored_run(store, name: str, values: dict[str, list[float]], *, dataset: str = "d", seed: int = 1,
               targets: tuple[str, ...] = ("y",), status: str = "finished", n_jobs: int | None = None,
               created_ns: int | None = None, tags: dict[str, str] | None = None, failed: int = 0,
               method_options: dict | None = None):
    """A run folder written through the store's API, without running anything (fast catalogue and compare tests).

    ``values`` is {method: [mae of repetition 0, 1, ...]}: one job per (method, repetition), each with the rows
    mae = v + k and rmse = 2 v + k of the k-th target (static mode, window 0, split test). ``status`` "running"
    leaves the run locked by this process, as a writer does.
    """
    cfg = {"name": name, "dataset": dataset, "seed": seed, "mode": "static", "interval": "t", "targets": list(targets),
           "methods": list(values), "method_options": method_options or {}}
    jobs = [(m, r, v) for m, vs in values.items() for r, v in enumerate(vs)]
    run = store.create(name, cfg, f"{seed:06d}{name}", {"python": "test"}, n_jobs or len(jobs), plugins=[], tags=tags)
    for m, r, v in jobs:
        rows = pd.DataFrame([{"dataset": dataset, "target": t, "mode": "static", "window": 0.0, "method": m,
                              "family": "test", "repetition": r, "split": "test", "metric": metric,
                              "value": v * f + k, "status": "ok"}
                             for k, t in enumerate(targets) for metric, f in (("mae", 1.0), ("rmse", 2.0))])
        run.write_job(f"{m}-r{r}", rows, {"status": "ok", "method": m})
    if created_ns is not None:
        run.update_info(created_ns=created_ns)
    if status != "running":
        run.update_info(status=status, finished_jobs=len(jobs), failed_jobs=failed)
    return run


def two_state_samples(seed: int = 0, n_seg: int = 3, n: int = 300):
    """Two coupled first-order outputs driven by two inputs (one also schedules), 10 Hz."""
    rng = np.random.default_rng(seed)
    frames = []
    for s in range(n_seg):
        t = np.arange(n) * 0.1
        u = np.sin(0.3 * t + rng.uniform(0, 6)) + 0.3 * rng.standard_normal(n).cumsum() / np.sqrt(n)
        v = np.cos(0.1 * t + rng.uniform(0, 6))
        y1, y2 = np.zeros(n), np.zeros(n)
        for i in range(1, n):
            a = -1.0 - 0.5 * v[i - 1]
            y1[i] = y1[i - 1] + 0.1 * (a * y1[i - 1] + u[i - 1])
            y2[i] = y2[i - 1] + 0.1 * (-2.0 * y2[i - 1] + 0.5 * y1[i - 1] + v[i - 1])
        frames.append(pd.DataFrame({"segment": f"s{s}", "time": t, "u": u, "v": v, "y1": y1, "y2": y2}))
    roles = {"u": "input", "v": "input", "y1": "output", "y2": "output"}
    ds = Dataset("two-state", pd.concat(frames, ignore_index=True), Schema.from_roles(roles), 0.1)
    return make_samples(ds, ["y1", "y2"], "simulation")
