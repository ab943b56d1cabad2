"""Long recordings: CPU time and peak memory against record length, for importing a CSV and fitting arx,
each beside the library doing the same work in the same process.

import: ``enginebench``'s import of a generated recording (a time column and 9 channels, 10 columns, every
digit written; ``datasets/importer.py``: parse, check every cell, time stamps and segments) against
``pandas.read_csv`` of the same file (parse only); the import parses with pandas' C parser too
(``datasets/readers.py``: pyarrow's CSV reader on one thread cost 1.4x its CPU here), so the ratio is the
price of the checks of every cell, time stamp and segment.

arx: ``ARX.fit`` with na = nb = 64 lags (nk = 1) on one record of a 2-input ARX system with noise, from
the samples (the lag products included), against scikit-learn's ``Ridge`` (alpha 1e-9) fitted on the same
lagged regression matrix (``methods.arx.regression``, built beforehand: its time is printed apart), and
the one-step RMSE of both on the training record (equal to ~1e-6 relative).

CPU is this process's CPU time (``time.process_time``: all threads; honest on a shared machine), best of
``--repeat``; peak is the rise of the resident set's high-water mark over the step (``/proc/self/clear_refs``
resets it; n/a where the kernel does not allow it).

identification (``--run-size N``): the README's identification protocol ("Identify your own system": records
split, init window of 20 samples, 3-fold k-fold selection on the free-run rmse, refit) with ``arx`` and ``narx`` at
their defaults, on a generated Wiener-Hammerstein record pair at 100 Hz (2 inputs, 1 output: a linear filter, a
static nonlinearity, another filter, output noise): an estimation record of N samples and a test record of
``--test-size`` (default N / 10). Printed per phase: writing the CSV files (not part of the work measured), the
import (``datasets show``), the whole ``run`` (it imports again), and each job's selection, fit and test
prediction from the run's own timings; wall, CPU and peak resident memory.

Usage: python benchmarks/long_records.py [--sizes 1e4 1e5 1e6] [--full (adds 1e7)] [--repeat 3]
       [--skip-import] [--skip-arx] [--run-size 1e7 [--test-size 1e6] [--methods arx narx]]
"""

from __future__ import annotations

import argparse
import gc
import os
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import scipy.signal

from enginebench.datasets.importer import import_table
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.dataset import Dataset
from enginebench.datasets.schema import Schema
from enginebench.methods.arx import ARX, regression
from enginebench.methods.freerun import training_trajectories

CHANNELS = 9
LAGS = 64


def _rss_kib(field: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def measure(fn: Callable[[], object], repeat: int) -> tuple[float, float | None, object]:
    """(best CPU seconds, peak rise in MB of the last call, the last result)."""
    best, peak, out = float("inf"), None, None
    for _ in range(repeat):
        out = None
        gc.collect()
        can = _reset_peak()
        base = _rss_kib("VmRSS")
        t = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t)
        hwm = _rss_kib("VmHWM")
        peak = (hwm - base) / 1024 if can and hwm is not None and base is not None else None
    return best, peak, out


def write_recording(folder: Path, n: int) -> Path:
    """A recording of ``n`` rows: time at 100 Hz and 9 channels (8 inputs, 1 output), and its import spec."""
    rng = np.random.default_rng(0)
    frame = pd.DataFrame({"t": np.arange(n) * 0.01})
    for k in range(CHANNELS):
        frame[f"c{k}"] = rng.normal(size=n).cumsum() / 100 + rng.normal(size=n)
    frame.to_csv(folder / f"rec{n}.csv", index=False)
    spec = folder / f"rec{n}.toml"
    spec.write_text(f'name = "rec{n}"\nfiles = ["rec{n}.csv"]\ntime = "t"\ndt = 0.01\n[columns]\n'
                    + "".join(f'c{k} = {{ role = "{"output" if k == CHANNELS - 1 else "input"}" }}\n'
                              for k in range(CHANNELS)), encoding="utf-8")
    return spec


def arx_samples(n: int):
    """One record of y = ARX(2 inputs, order 4) + noise, as simulation-mode training samples."""
    rng = np.random.default_rng(1)
    u = rng.normal(size=(n, 2))
    a = np.poly([0.9, 0.7, 0.5 + 0.2j, 0.5 - 0.2j]).real
    y = scipy.signal.lfilter([0, 0.5, 0.2], a, u[:, 0]) + scipy.signal.lfilter([0, -0.3, 0.1], a, u[:, 1])
    y += 0.01 * rng.normal(size=n)
    frame = pd.DataFrame({"segment": "r", "time": np.arange(n) * 0.01, "u1": u[:, 0], "u2": u[:, 1], "y": y})
    ds = Dataset("arx", frame, Schema.from_roles({"u1": "input", "u2": "input", "y": "output"}), 0.01)
    return SamplePool(RawSegments.from_dataset(ds), ["y"], "simulation").materialize()


def one_step_rmse(theta: np.ndarray, Phi: np.ndarray, y: np.ndarray) -> float:
    return float(np.sqrt(np.mean((Phi @ theta - y) ** 2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    ap.add_argument("--full", action="store_true", help="add 1e7 rows (about 1 GB of CSV; minutes)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-import", action="store_true")
    ap.add_argument("--skip-arx", action="store_true")
    ap.add_argument("--run-size", type=float, default=None,
                    help="identification of an estimation record of this many samples (alone: skips the rest)")
    ap.add_argument("--test-size", type=float, default=None, help="test record samples (default run size / 10)")
    ap.add_argument("--methods", nargs="+", default=["arx", "narx"])
    args = ap.parse_args()
    if args.run_size is not None:
        n = int(args.run_size)
        identification(n, int(args.test_size) if args.test_size else max(n // 10, 1000), args.methods)
        return
    sizes = [int(s) for s in args.sizes] + ([10**7] if args.full and 10**7 not in args.sizes else [])
    print(f"cpus {os.cpu_count()}, load {os.getloadavg()[0]:.1f}; CPU s = process CPU time (best of {args.repeat}), "
          "peak MB = resident high-water rise")
    if not args.skip_import:
        print(f"\nimport of a CSV of n rows x {CHANNELS + 1} columns")
        print(f"{'rows':>10} {'MB':>7} | {'pandas CPU s':>12} {'peak MB':>8} | {'import CPU s':>12} {'peak MB':>8} | "
              f"{'ratio':>5}")
        with tempfile.TemporaryDirectory() as tmp:
            for n in sizes:
                spec = write_recording(Path(tmp), n)
                csv = spec.with_suffix(".csv")
                repeat = args.repeat if n < 10**7 else 1
                p_cpu, p_peak, frame = measure(lambda: pd.read_csv(csv), repeat)
                del frame
                i_cpu, i_peak, ds = measure(lambda: import_table(spec), repeat)
                assert len(ds.frame) == n
                del ds
                fmt = lambda v: "n/a" if v is None else f"{v:.0f}"  # noqa: E731
                print(f"{n:>10,} {csv.stat().st_size / 1e6:>7.1f} | {p_cpu:>12.2f} {fmt(p_peak):>8} | {i_cpu:>12.2f} "
                      f"{fmt(i_peak):>8} | {i_cpu / p_cpu:>5.2f}")
                csv.unlink()
    if not args.skip_arx:
        from sklearn.linear_model import Ridge

        print(f"\narx, na = nb = {LAGS}, nk = 1, 2 inputs ({LAGS * 3 + 1} parameters), one record of n samples")
        print(f"{'samples':>10} | {'arx fit CPU s':>13} {'peak MB':>8} | {'lag matrix s':>12} {'Ridge CPU s':>11} "
              f"{'peak MB':>8} | {'ratio':>5} | {'RMSE rel. diff':>14}")
        params = {"order": LAGS, "nk": 1}
        for n in sizes:
            if n > 2 * 10**6 and not args.full:
                continue
            train = arx_samples(n)
            method = ARX()
            repeat = args.repeat if n < 10**7 else 1
            a_cpu, a_peak, fitted = measure(lambda: method.fit(train, params, np.random.default_rng(0)), repeat)
            traj = training_trajectories("arx", train)
            t = time.process_time()
            Phi, y = regression(traj, 0, LAGS, LAGS, 1)
            build = time.process_time() - t
            r_cpu, r_peak, ridge = measure(lambda: Ridge(alpha=1e-9, fit_intercept=False).fit(Phi, y), repeat)
            ours = np.r_[fitted.a[0], fitted.b[0].ravel(), fitted.c[0]]
            e_ours, e_ridge = one_step_rmse(ours, Phi, y), one_step_rmse(ridge.coef_, Phi, y)
            fmt = lambda v: "n/a" if v is None else f"{v:.0f}"  # noqa: E731
            print(f"{n:>10,} | {a_cpu:>13.2f} {fmt(a_peak):>8} | {build:>12.2f} {r_cpu:>11.2f} {fmt(r_peak):>8} | "
                  f"{a_cpu / r_cpu:>5.2f} | {abs(e_ours - e_ridge) / e_ridge:>14.1e}")
            del Phi, y, train


# -- identification of a long record ---------------------------------------------------------------------------
def wiener_hammerstein(n: int, seed: int) -> pd.DataFrame:
    """``n`` samples at 100 Hz of a 2-input Wiener-Hammerstein system: band-limited random inputs, a second-order
    filter of each, a static nonlinearity (tanh plus a square), a first-order output filter, 1 % output noise."""
    rng = np.random.default_rng(seed)
    u = scipy.signal.lfilter([0.05], [1, -0.95], rng.normal(size=(n, 2)), axis=0) * 3
    x = (scipy.signal.lfilter([0, 0.3, 0.1], [1, -1.5, 0.7], u[:, 0])
         + 0.5 * scipy.signal.lfilter([0, 0.2], [1, -0.8], u[:, 1]))
    y = scipy.signal.lfilter([0.4], [1, -0.6], np.tanh(x) + 0.3 * x ** 2)
    y += 0.01 * y.std() * rng.normal(size=n)
    return pd.DataFrame({"throttle": u[:, 0], "speed": u[:, 1], "T_exh": y})


def _phase(label: str, fn: Callable[[], object]) -> object:
    gc.collect()
    can = _reset_peak()
    base = _rss_kib("VmRSS")
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    wall, cpu = time.perf_counter() - w, time.process_time() - c
    hwm = _rss_kib("VmHWM")
    peak = f"{(hwm - base) / 1024:.0f}" if can and hwm is not None and base is not None else "n/a"
    print(f"{label:<34} {wall:>9.1f} {cpu:>9.1f} {peak:>9}   (process RSS after: "
          f"{(_rss_kib('VmRSS') or 0) / 1024:.0f} MB)", flush=True)
    return out


def identification(n: int, n_test: int, methods: list[str]) -> None:
    """The README's identification run on an estimation record of ``n`` samples (module docstring)."""
    from enginebench.api import run

    print(f"identification: estimation record of {n:,} samples, test record of {n_test:,} (100 Hz), methods "
          f"{', '.join(methods)} at their defaults; cpus {os.cpu_count()}, load {os.getloadavg()[0]:.1f}")
    print(f"{'phase':<34} {'wall s':>9} {'CPU s':>9} {'peak MB':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)

        def write() -> None:
            wiener_hammerstein(n, 0).to_csv(folder / "estimation.csv", index=False)
            wiener_hammerstein(n_test, 1).to_csv(folder / "test.csv", index=False)

        _phase("write the CSV files (not measured)", write)
        (folder / "bench.toml").write_text(
            'name = "long-bench"\nfiles = ["estimation.csv", "test.csv"]\ndt = 0.01\n[columns]\n'
            'throttle = { role = "input" }\nspeed = { role = "input" }\nT_exh = { role = "output" }\n',
            encoding="utf-8")
        _phase("import (datasets show)", lambda: import_table(folder / "bench.toml"))
        experiment = {
            "name": "long-ident", "dataset": str(folder / "bench.toml"), "targets": ["T_exh"], "mode": "simulation",
            "repetitions": 1, "train_size": 0, "init_samples": 20,
            "split": {"kind": "records", "train": ["estimation"], "test": ["test"]},
            "selection": {"kind": "kfold", "folds": 3, "criterion": "rmse"},
            "methods": {m: {} for m in methods},
        }
        result = _phase(f"run ({', '.join(methods)}, 1 worker)",
                        lambda: run(experiment, workers=1, store=folder / "runs"))
        jobs = result.jobs()  # type: ignore[attr-defined]
        for _, job in jobs.iterrows():
            times = "  ".join(f"{k.removeprefix('time:')} {job[k]:.1f}" for k in jobs.columns
                              if k.startswith("time:") and pd.notna(job[k]))
            picks = ", ".join(f"{k.removeprefix('param:')} {job[k]:g}" for k in jobs.columns
                              if k.startswith("param:") and pd.notna(job[k]))
            print(f"  {job['method']:<8} {job['status']:<7} {times}  picks: {picks}  {job.get('reason') or ''}")
            if job.get("warnings"):
                print(f"    warnings: {job['warnings']}")
        table = result.table(metrics=["rmse"])  # type: ignore[attr-defined]
        print(table[["method", "split", "metric", "mean"]].to_string(index=False))


if __name__ == "__main__":
    main()
