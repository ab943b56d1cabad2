"""A test-bench campaign at the size users bring, end to end through the command line, timed.

Writes a synthetic campaign like the one a new user brought (32 headerless CSV files of
13,000 samples at 10 Hz, 5 inputs, 8 outputs: first- and second-order lags of static
nonlinear maps of the inputs, with sensor noise), an import spec with ``header = false`` and a
glob, and an experiment with ``naive-mean`` and ``arx`` on three outputs: simulation mode,
records split (20 training records, 12 test records: 260,000 training samples), k-fold
selection over the training records, a 50-sample init window. Then runs ``enginebench run``
in a child process and prints its wall time, CPU time and peak memory (the target: under 2
minutes on 2 cores).

Usage: python benchmarks/campaign_scale.py [--records 32] [--train 20] [--samples 13000] [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.signal

INPUTS = ("speed", "load", "lambda", "spark", "egr")
OUTPUTS = ("nox", "co", "hc", "pn", "t_manifold", "t_turbine", "t_cat", "torque")


def record(rng: np.random.Generator, n: int, dt: float) -> np.ndarray:
    """(n, 13): 5 inputs held for random dwell times (a transient test cycle), 8 lagged nonlinear outputs."""
    U = np.empty((n, len(INPUTS)))
    for j in range(len(INPUTS)):
        steps = np.cumsum(rng.integers(20, 400, size=n // 20 + 1))
        levels = rng.uniform(-1, 1, size=len(steps))
        U[:, j] = levels[np.searchsorted(steps, np.arange(n), side="right")]
    U = scipy.signal.lfilter([0.2], [1, -0.8], U, axis=0)
    Y = np.empty((n, len(OUTPUTS)))
    maps = [np.exp(U[:, 0] * U[:, 1]), U[:, 1] ** 2 - U[:, 2], np.tanh(3 * U[:, 3]) + U[:, 4],
            np.maximum(U[:, 2], 0) * U[:, 0], U[:, 0] + U[:, 1], U[:, 1] * (1 + U[:, 3]), U[:, 0] * U[:, 4],
            U[:, 1] - 0.3 * U[:, 2] ** 2]
    for k, (drive, tau) in enumerate(zip(maps, (0.5, 1.0, 2.0, 0.3, 20.0, 10.0, 60.0, 0.2))):
        a = np.exp(-dt / tau)
        Y[:, k] = scipy.signal.lfilter([1 - a], [1, -a], drive) + 0.02 * rng.standard_normal(n)
    return np.hstack([U, Y])


def write_campaign(folder: Path, records: int, train: int, samples: int, seed: int = 0) -> tuple[Path, Path]:
    rng = np.random.default_rng(seed)
    dt = 0.1
    names = [f"raw_{i + 1:03d}" for i in range(records)]
    for name in names:
        np.savetxt(folder / f"{name}.csv", record(rng, samples, dt), delimiter=",", fmt="%.6e")
    columns = "\n".join([f'{c} = {{ role = "input" }}' for c in INPUTS] + [f'{c} = {{ role = "output" }}' for c in OUTPUTS])
    spec = folder / "campaign.toml"
    spec.write_text(f'name = "campaign"\ndt = {dt}\nheader = false\nfiles = ["raw_*.csv"]\n[columns]\n{columns}\n')
    experiment = folder / "experiment.toml"
    quoted = lambda xs: ", ".join(f'"{x}"' for x in xs)  # noqa: E731
    experiment.write_text(
        f'name = "campaign-arx"\ndataset = "campaign.toml"\ntargets = ["nox", "t_manifold", "t_cat"]\n'
        f'mode = "simulation"\nrepetitions = 1\ntrain_size = 0\ninit_samples = 50\n'
        f'[split]\nkind = "records"\ntrain = [{quoted(names[:train])}]\ntest = [{quoted(names[train:])}]\n'
        f'[selection]\nkind = "kfold"\nfolds = 3\ncriterion = "rmse"\n[methods.naive-mean]\n[methods.arx]\n')
    return spec, experiment


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=int, default=32)
    ap.add_argument("--train", type=int, default=20)
    ap.add_argument("--samples", type=int, default=13_000)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="enginebench-campaign-") as tmp:
        folder = Path(tmp)
        t0 = time.perf_counter()
        _, experiment = write_campaign(folder, args.records, args.train, args.samples)
        print(f"wrote {args.records} headerless files of {args.samples} samples ({args.train * args.samples:,} "
              f"training samples) in {time.perf_counter() - t0:.1f} s")
        env = {**os.environ, "ENGINEBENCH_STORE": str(folder / "runs"), "ENGINEBENCH_DATA": str(folder / "data")}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        exe = shutil.which("enginebench") or sys.exit("enginebench is not on PATH; pip install -e . first")
        done = subprocess.run([exe, "run", str(experiment), "-j",
                               str(args.jobs), "--quiet"], env=env, cwd=folder, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        print(done.stdout[-3000:], done.stderr[-2000:], sep="\n")
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        print(f"enginebench run (naive-mean, arx; 3 outputs; {args.jobs} workers): exit {done.returncode}, "
              f"wall {wall:.1f} s, CPU {cpu:.1f} s, peak memory of the largest process {after.ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
