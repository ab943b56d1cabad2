"""Feature rankings for the problems of a stored run, written next to its jobs."""

from __future__ import annotations

from typing import Iterator

import numpy as np
import pandas as pd

from enginebench.errors import MethodError
from enginebench.experiments.jobs import JOINT, stable_int, subsample
from enginebench.experiments.ranking import rank_features
from enginebench.experiments.runner import prepare
from enginebench.experiments.spec import from_dict
from enginebench.results.run_folder import Run


def rank_run(run: Run, methods: list[str] | None = None, repetition: int = 0) -> Iterator[tuple[str, pd.DataFrame]]:
    """Yield (key, ranking) per (target, window, split, method) and store each in the run."""
    spec = from_dict(run.config(), origin=f"run {run.id}")
    ctx = prepare(spec)
    chosen = methods or [m for m, meth in ctx.methods.items() if meth.family != "baseline" and meth.family != "physical"]
    unknown = [m for m in chosen if m not in ctx.methods]
    if unknown:
        raise MethodError(f"run {run.id} did not run method(s) {', '.join(unknown)}; it ran {', '.join(ctx.methods)}")
    for (target, window, split), problem in ctx.problems.items():
        if target == JOINT:  # features are ranked target by target
            continue
        sub_rng = np.random.default_rng([spec.seed, repetition, stable_int(split)])
        train = problem.train.take(subsample(len(problem.train), spec.train_size, sub_rng))
        for name in chosen:
            rng = np.random.default_rng([spec.seed, repetition, stable_int(name), stable_int("rank")])
            table = rank_features(ctx.methods[name], train, spec.selection, rng)
            table.insert(0, "method", name)
            table.insert(0, "window", window)
            table.insert(0, "target", target)
            key = f"{target}__w{window:g}__{split}__{name}"
            run.write_table(f"rankings/{key}.parquet", table)
            yield key, table
