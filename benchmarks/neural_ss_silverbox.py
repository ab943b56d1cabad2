"""neural-ss (and optionally gru) on Silverbox with their default options: training wall time and test RMSE.

Runs the built-in experiment ``silverbox`` (or ``silverbox-quick`` with ``--quick``) as
``enginebench run`` does for repetition 0: the estimation part (the multisine record
SNLS80mV[40650:127400]) is the training record, the test record is the 'arrow'
SNLS80mV[50:40575] simulated in free run after the experiment's 50-sample init window.
The defaults search nothing (one state size), so no model selection is run: one fit on
the estimation part, one free run of the test part. Prints the device, the training wall
time, the steps run (early stopping), the test RMSE in mV (all evaluated samples and the
first 32,000, the part whose amplitude stays inside the estimation data's), and whether
the run diverged. The issue's target: neural-ss trains in under 10 minutes on 2 CPU cores.

The dataset is imported from ``--data`` (default ``../shared/data``) into a temporary data
home unless it is already imported (``enginebench datasets import silverbox --from DIR``).

Usage: python benchmarks/neural_ss_silverbox.py [--device cpu|cuda|auto] [--methods neural-ss gru]
       [--quick] [--threads N] [--option key=value ...] [--data DIR]
"""

from __future__ import annotations

import argparse
import ast
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from enginebench import registry
from enginebench.datasets import catalog
from enginebench.errors import EngineBenchError
from enginebench.experiments.jobs import Job, final_fit_rng, training_samples
from enginebench.experiments.runner import prepare
from enginebench.experiments.spec import load_spec
from enginebench.results import metrics

FIRST = 32000
"""Extra RMSE over the first FIRST evaluated test samples (inside the estimation data's amplitude)."""


def _ensure_dataset(data: Path, home: Path) -> None:
    """Import the built-in silverbox from ``data`` into ``home`` unless the current data home has it."""
    try:
        catalog.locate("silverbox")
        return
    except EngineBenchError:
        pass
    os.environ["ENGINEBENCH_DATA"] = str(home)
    try:
        catalog.locate("silverbox")
    except EngineBenchError:
        catalog.import_builtin("silverbox", data / "silverbox")


def _value(text: str) -> object:
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def run(experiment: str, methods: list[str], device: str, extra: dict[str, object]) -> None:
    spec = load_spec(experiment)
    ctx = prepare(spec)
    for (target, window, split), problem in ctx.problems.items():
        train = training_samples(spec, problem, 0, split)
        test = problem.parts["test"]
        test = test.materialize() if hasattr(test, "materialize") else test
        view = test.without_targets()
        y = test.y[:, 0]
        print(f"{experiment}: training rows {len(train):,}, test rows {len(y):,} after a {spec.init_samples}-sample "
              f"init window, output SD {y.std() * 1e3:.2f} mV", flush=True)
        for name in methods:
            method = registry.get(name)(device=device, **extra)
            rng = final_fit_rng(spec, Job(target, window, split, name, 0))  # as the run's final fit
            params = {k: v[0] for k, v in method.search_space(train).items()}
            t0 = time.perf_counter()
            fitted = method.fit(train, params, rng)
            t1 = time.perf_counter()
            pred = method.predict(fitted, view)
            t2 = time.perf_counter()
            yhat = np.concatenate(list(pred))[:, 0]
            info = method.describe(fitted)
            print(f"  {name:<10} device {info['device']:<6} train {t1 - t0:7.1f} s  predict {t2 - t1:5.1f} s  "
                  f"steps {info['steps_run']} (best {info['best_step']}, epochs {info['epochs']})  "
                  f"nx {info['nx']} lags {info['lags']} horizon {info['horizon']}  "
                  f"test rmse {metrics.rmse(y, yhat) * 1e3:.3f} mV  first {FIRST:,}: "
                  f"{metrics.rmse(y[:FIRST], yhat[:FIRST]) * 1e3:.3f} mV  fit {metrics.fit(y, yhat):.2f} %  "
                  f"diverged {int(np.sum(pred.diverged))}/{len(pred)}", flush=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", help="torch device option of the methods (cpu, cuda, auto)")
    parser.add_argument("--methods", nargs="+", default=["neural-ss"])
    parser.add_argument("--quick", action="store_true", help="silverbox-quick: 20,000 training samples")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (the option cpu_threads)")
    parser.add_argument("--option", nargs="*", default=[], help="extra method options key=value (e.g. steps=500)")
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "data")
    args = parser.parse_args(argv)
    extra = {k: _value(v) for k, v in (item.split("=", 1) for item in args.option)}
    if args.threads is not None:
        extra["cpu_threads"] = args.threads
    cuda = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none"
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"CUDA device: {cuda}; options {extra}", flush=True)
    with tempfile.TemporaryDirectory(prefix="enginebench-neural-ss-") as home:
        _ensure_dataset(args.data, Path(home))
        run("silverbox-quick" if args.quick else "silverbox", args.methods, args.device, extra)


if __name__ == "__main__":
    main()
