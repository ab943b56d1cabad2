"""An integrating system with defaults: a positioning-like record pair (issue 30).

A prismatic axis is simulated here: a mass driven by a motor force against viscous and Coulomb
friction and a constant offset force, M q'' = tau - Fv q' - Fc sign(q') - F0, under a PD position
controller tracking a smooth random reference, sampled at 1 kHz, ~25,000 samples per record
(the size and kind of the published electro-mechanical positioning benchmark; the numbers are
chosen here, not taken from it). The recorded input is the motor force tau, the output the
measured position q (noise 10 um): from force to position the plant integrates twice, so a free
run drifts unless the model carries the integrators and the friction.

``enginebench run`` is called as a user would (records split, a 50-sample init window, 2-fold
selection, every method's defaults) and the test RMSE of each method is printed in mm, with the
jobs that failed and their reasons (every failure must say what to do).

Usage: python benchmarks/positioning_like.py [--methods naive-mean arx narx ...] [--seed 0]
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

IMPORT_SPEC = """name = "positioning-like"
files = ["estimation.csv", "test.csv"]
dt = 0.001
[columns]
tau = { role = "input", unit = "N" }
q = { role = "output", unit = "mm" }
"""

EXPERIMENT = """name = "positioning-like"
dataset = "{dataset}"
targets = ["q"]
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
DEFAULT_METHODS = ["naive-mean", "arx", "narx", "nfir", "boost-fir", "sindy", "moe", "n4sid"]


def simulate(rng: np.random.Generator, n: int = 24841, dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """(tau [N], q [mm]) of the closed loop, 10 Euler substeps per sample, controller at the sample rate."""
    M, Fv, Fc, F0 = 95.0, 200.0, 20.0, -3.0
    Kp, Kd = 2.0e4, 1.5e3
    # reference: a smooth random path in [0.02, 0.22] m, its knots every 0.5 s, cubic-like by double smoothing
    knots = rng.uniform(0.02, 0.22, n // 500 + 2)
    r = np.interp(np.arange(n), np.arange(len(knots)) * 500, knots)
    kernel = np.ones(200) / 200
    r = np.convolve(np.convolve(r, kernel, mode="same"), kernel, mode="same")
    r[:400] = r[400]
    q, v = r[0], 0.0
    tau = np.empty(n)
    pos = np.empty(n)
    h = dt / 10
    for t in range(n):
        meas = q + 1e-5 * rng.normal()
        pos[t] = meas
        tau[t] = Kp * (r[t] - meas) - Kd * v
        for _ in range(10):
            acc = (tau[t] - Fv * v - Fc * np.tanh(v / 1e-3) - F0) / M
            v += h * acc
            q += h * v
    return tau, 1e3 * pos


def write_pair(folder: Path, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    for name in ("estimation", "test"):
        tau, q = simulate(rng)
        np.savetxt(folder / f"{name}.csv", np.column_stack([tau, q]), delimiter=",", header="tau,q", comments="",
                   fmt="%.8g")
    spec = folder / "positioning.toml"
    spec.write_text(IMPORT_SPEC)
    return spec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", nargs="+", default=DEFAULT_METHODS)
    parser.add_argument("--keep", type=Path, help="write the records and the run store here (kept)")
    args = parser.parse_args()
    methods = "\n".join(f"[methods.{m}]" for m in args.methods)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, "ENGINEBENCH_STORE": str(root / "runs"), "ENGINEBENCH_DATA": str(root / "data")}
        dataset = write_pair(root, args.seed)
        exp = root / "experiment.toml"
        exp.write_text(EXPERIMENT.format(seed=args.seed, dataset=dataset, methods=methods))
        start = time.perf_counter()
        done = subprocess.run(CLI + ["run", str(exp), "--quiet"], env=env, capture_output=True, text=True)
        took = time.perf_counter() - start
        if done.returncode not in (0, 1):
            print(done.stdout, done.stderr)
            raise SystemExit(done.returncode)
        table = subprocess.run(CLI + ["table", "latest", "--metrics", "rmse,fit"], env=env,
                               capture_output=True, text=True).stdout
        notes = subprocess.run(CLI + ["runs", "show", "latest"], env=env, capture_output=True, text=True).stdout
        print(f"run: {took:.0f} s wall (rc {done.returncode})\n{table}")
        print("\n".join(line for line in notes.splitlines() if "fail" in line.lower() or "error" in line.lower()))


if __name__ == "__main__":
    main()
