"""A MoE grid trained side by side (``batch_grid = true``) against one run after another, in one process.

The grid is the method's default search space (2-4 experts x beta2 0.1, 1 x lr 1e-3, 1e-2:
12 training runs), the options those of turboshaft-trq's torque MoE (standard-day correction,
derivative loss only; WF, internal, is not among the inputs here), the rows the turboshaft training part (``--train-rows`` of whole
trajectories, 200,000 as the experiment). Both paths first train one epoch untimed, so
torch.compile's graphs (``--compile``, as fits of >= 20,000 steps do) are built before the
clock starts; then each trains the grid for ``--epochs`` epochs. Printed: seconds per path,
the ratio, and the largest difference between the two paths' weights (float32: the batched
kernels sum in another order; the suite checks float64 equality).

Usage: python benchmarks/moe_grid.py [--size full|small] [--train-rows N] [--epochs N] [--compile | --no-compile]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from enginebench.datasets import catalog
from enginebench.datasets.pools import make_samples
from enginebench.datasets.splits import make_splits
from enginebench.experiments.jobs import subsample_segments
from enginebench.experiments.spec import load_spec
from enginebench.method import grid_points
from enginebench.methods.moe import MoE, grid as grid_training, training


def _load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=["small", "full"], default="full")
    parser.add_argument("--train-rows", type=int, default=load_spec("turboshaft-trq").train_size)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--compile", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    torch.set_num_threads(1)
    ds = catalog.load("turboshaft", variant=args.size)
    train_all = make_samples(make_splits(ds, kind="published")[0].train, ["TRQ"], "simulation")
    rng = np.random.default_rng(args.seed)
    sizes = np.array([len(s) for s in train_all.segments])
    train = train_all.take(subsample_segments(sizes, args.train_rows, rng)) if args.train_rows else train_all
    opts = dict(load_spec("turboshaft-trq").method_options["moe-nfir"]["downstream_options"])
    opts["correct"] = {k: v for k, v in opts["correct"].items() if k in train.target_names + train.input_names}
    method = {flag: MoE(**opts, batch_grid=flag, compile=args.compile) for flag in (True, False)}
    grid = [{**point, "epochs": args.epochs} for point in grid_points(method[True].search_space(train))]
    print(f"MoE grid: {len(grid)} runs, {len(train):,} training rows ({len(train.segments)} trajectories), TRQ, "
          f"batch {method[True].options['batch_size']}, {args.epochs} epochs, compile {args.compile}, 1 thread; {_load()}")
    saved = training.COMPILE_MIN_STEPS, grid_training.COMPILE_MIN_STEPS
    training.COMPILE_MIN_STEPS = grid_training.COMPILE_MIN_STEPS = 0 if args.compile else 10**12
    try:
        for flag in (True, False):  # untimed: TV derivatives into the cache, compiled graphs built
            list(method[flag].fit_grid(train, [{**p, "epochs": 1} for p in grid], np.random.default_rng(1)))
        walls, models = {}, {}
        for flag in (True, False):
            t0 = time.perf_counter()
            models[flag] = dict(method[flag].fit_grid(train, grid, np.random.default_rng(args.seed)))
            walls[flag] = time.perf_counter() - t0
            print(f"  {'side by side' if flag else 'one by one':<13} {walls[flag]:8.2f} s  "
                  f"({walls[flag] / len(grid) / args.epochs:.3f} s per run-epoch); {_load()}")
    finally:
        training.COMPILE_MIN_STEPS, grid_training.COMPILE_MIN_STEPS = saved
    worst = max(
        float(np.max(np.abs(models[True][i].weights[k] - w))) for i, m in models[False].items() for k, w in m.weights.items()
    )
    print(f"  ratio one by one / side by side: {walls[False] / walls[True]:.2f}x; largest weight difference {worst:.2e}")


if __name__ == "__main__":
    main()
