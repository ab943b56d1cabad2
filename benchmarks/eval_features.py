"""The feature path of a kernel method's prediction: window features, stacking, standardisation.

Times, in one process on the same synthetic window data, the former path (window features
gathered per input and per target, transposed into their own arrays and joined with
``hstack``; the batch's ``Samples.X`` stacked; ``StandardScaler.transform``; a nan/inf mask)
against the current one (``SamplePool`` writing the window features once into one array,
``kernels.standardize_rows`` scaling the segments' blocks into one array, the finiteness
check on one sum), checks that both give the same numbers bit for bit, and prints the ratio.
Sizes as one prediction batch of the full marine experiment (20,000 rows, 40 inputs,
Delta = 30 s at 3 s: 11 lags, 450 features).

Usage: python benchmarks/eval_features.py [--rows 20000] [--inputs 40] [--lags 10] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from threadpoolctl import threadpool_limits

from enginebench.datasets.pools import RawSegments, SamplePool, SegmentArrays
from enginebench.methods.numerics.kernels import make_scaler, standardize_rows
from enginebench.methods.krls import _check_finite


def former(U: np.ndarray, Y: np.ndarray, rows: np.ndarray, lags: int, scaler) -> np.ndarray:
    """The path as it was: gather, transpose-copy, hstack, stack, transform, mask."""
    past = rows[:, None] - np.arange(lags + 1)[None, :]
    X_in = U[past].transpose(0, 2, 1).reshape(len(rows), -1)
    X_out = Y[past[:, 1:]].transpose(0, 2, 1).reshape(len(rows), -1)
    X = np.concatenate([np.hstack([X_in, X_out])])  # Samples.X of a one-segment batch
    if (~np.isfinite(X)).any():
        raise AssertionError("non-finite features")
    return scaler.transform(X)


def current(pool: SamplePool, rows: np.ndarray, scaler) -> np.ndarray:
    batch = pool.take(rows)
    Xe = standardize_rows(scaler, [s.X for s in batch.segments])
    _check_finite(Xe, "features", batch.feature_names)
    return Xe


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=20_000)
    parser.add_argument("--inputs", type=int, default=40)
    parser.add_argument("--lags", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    n = args.rows + args.lags
    U, Y = rng.normal(size=(n, args.inputs)) * 50 + 300, rng.normal(size=(n, 1)) * 20 + 400
    t = np.arange(n) * 3.0
    raw = RawSegments(dataset="synthetic", dt=3.0, inputs=tuple(f"u{j}" for j in range(args.inputs)),
                      outputs=("y",), internals=(), units={},
                      segments=(SegmentArrays(id="s", t=t, U=U, Y=Y, Z=None),))
    pool = SamplePool(raw, ["y"], "window", args.lags * 3.0)
    rows = np.arange(args.rows)
    scaler = make_scaler(pool.take(rng.choice(args.rows, 1000, replace=False)).X)
    with threadpool_limits(1):
        a = former(U, Y, rows + args.lags, args.lags, scaler)
        b = current(pool, rows, scaler)
        assert np.array_equal(a, b), "the two paths differ"
        times = {"former": [], "current": []}
        for _ in range(args.repeats):  # alternating, best of each
            t0 = time.perf_counter(); former(U, Y, rows + args.lags, args.lags, scaler)
            times["former"].append(time.perf_counter() - t0)
            t0 = time.perf_counter(); current(pool, rows, scaler)
            times["current"].append(time.perf_counter() - t0)
    f, c = min(times["former"]), min(times["current"])
    print(f"{args.rows:,} rows x {a.shape[1]} features, 1 thread, load {os.getloadavg()[0]:.1f}: same numbers; "
          f"former {f * 1e3:.1f} ms, current {c * 1e3:.1f} ms per batch: {f / c:.2f}x")


if __name__ == "__main__":
    main()
