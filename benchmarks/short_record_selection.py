"""Selection on a short record: does the search past the grid's edge help or chase noise? (issue 30)

A tanks-like record pair is simulated here (two cascaded water tanks with square-root outflows and an
overflow at the top of each tank, sampled every 4 s, 1,024 samples per record, a seeded low-pass
random input, output noise of 1 % of the output's span): the situation where free-run k-fold
scores are noisy. ``enginebench run`` is called as a user would (records split, a 50-sample
init window, 2-fold selection, the methods' defaults) once per seed, and the test RMSE of every
method is printed with the mean over seeds, together with the grid-edge warnings the run gave.

Compare two checkouts by running this script with each on ``PYTHONPATH`` (or once before and once
after a change): the figures are the same work on the same seeded records.

Usage: python benchmarks/short_record_selection.py [--seeds 0 1 2] [--methods naive-mean arx narx]
       [--option moe.epochs_grid=[100]]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

IMPORT_SPEC = """name = "tanks-like"
files = ["estimation.csv", "test.csv"]
dt = 4.0
[columns]
u = {{ role = "input", unit = "V" }}
y = {{ role = "output", unit = "V" }}
"""

EXPERIMENT = """name = "tanks-like-{seed}"
dataset = "{dataset}"
targets = ["y"]
mode = "simulation"
repetitions = 1
seed = {seed}
train_size = 0
init_samples = 50
[split]
kind = "records"
train = ["estimation"]
test = ["test"]
[selection]
kind = "kfold"
folds = 2
criterion = "rmse"
{methods}
"""


CLI = [sys.executable, "-c", "from enginebench.cli.main import cli; cli()"]
"""The command line in this interpreter, so that ``PYTHONPATH`` picks the checkout measured."""


def simulate(rng: np.random.Generator, n: int = 1024, dt: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """(u, y): two cascaded tanks, Euler steps of dt / 40, overflow at level 10, noise 1 % of the span."""
    steps = 40
    white = rng.normal(size=n // 16 + 2)
    u = np.clip(4.0 + 1.6 * np.repeat(white, 16)[:n], 0.0, 10.0)  # held for 64 s: slow against the tanks
    k1, k2, k3, k4 = 0.05, 0.05, 0.05, 0.03
    x1 = x2 = 3.0
    y = np.empty(n)
    h = dt / steps
    for t in range(n):
        for _ in range(steps):
            q1 = k1 * np.sqrt(max(x1, 0.0))
            x1 = min(x1 + h * (k4 * u[t] - q1), 10.0)
            x2 = min(x2 + h * (k2 * np.sqrt(max(x1, 0.0)) - k3 * np.sqrt(max(x2, 0.0))), 10.0)
        y[t] = x2
    y = y + 0.01 * np.ptp(y) * rng.normal(size=n)
    return u, y


def write_pair(folder: Path, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    for name in ("estimation", "test"):
        u, y = simulate(rng)
        np.savetxt(folder / f"{name}.csv", np.column_stack([u, y]), delimiter=",", header="u,y", comments="",
                   fmt="%.6f")
    spec = folder / "tanks.toml"
    spec.write_text(IMPORT_SPEC.format())
    return spec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--methods", nargs="+", default=["naive-mean", "arx", "narx"])
    parser.add_argument("--option", action="append", default=[], metavar="METHOD.KEY=TOML",
                        help="an option of one method, e.g. moe.epochs_grid=[100] (the setting before a change)")
    args = parser.parse_args()
    options: dict[str, list[str]] = {m: [] for m in args.methods}
    for item in args.option:
        key, value = item.split("=", 1)
        method, option = key.rsplit(".", 1)
        options[method].append(f"{option} = {value}")
    methods = "\n".join("\n".join([f"[methods.{m}]", *options[m]]) for m in args.methods)
    rmse: dict[str, list[float]] = {m: [] for m in args.methods}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        env = {**os.environ, "ENGINEBENCH_STORE": str(root / "runs"), "ENGINEBENCH_DATA": str(root / "data")}
        for seed in args.seeds:
            folder = root / f"seed{seed}"
            folder.mkdir()
            dataset = write_pair(folder, seed)
            exp = folder / "experiment.toml"
            exp.write_text(EXPERIMENT.format(seed=seed, dataset=dataset, methods=methods))
            start = time.perf_counter()
            subprocess.run(CLI + ["run", str(exp), "--quiet"], env=env,
                           check=True, capture_output=True, text=True)
            took = time.perf_counter() - start
            shown = subprocess.run(CLI + ["table", "latest", "--format",
                                    "csv"], env=env, check=True, capture_output=True, text=True)
            notes = subprocess.run(CLI + ["runs", "show", "latest"], env=env,
                                   check=True, capture_output=True, text=True).stdout
            rows = [line.split(",") for line in shown.stdout.strip().splitlines()]
            header = rows[0]
            for row in rows[1:]:
                record = dict(zip(header, row))
                if record.get("split") == "test" and record.get("metric") == "rmse" and record.get("method") in rmse:
                    rmse[record["method"]].append(float(record["mean"]))
            edges = [line.strip() for line in notes.splitlines() if "grid edge" in line or "hard bound" in line]
            print(f"seed {seed}: {took:.0f} s; " + ", ".join(f"{m} {v[-1]:.4f}" for m, v in rmse.items() if v)
                  + ("".join(f"\n  {e}" for e in edges)))
    print("mean test RMSE [V] over seeds " + " ".join(map(str, args.seeds)) + ": "
          + ", ".join(f"{m} {np.mean(v):.4f}" for m, v in rmse.items() if v))


if __name__ == "__main__":
    main()
