"""A real engine campaign against the virtual-sensor baseline engine teams use, on the same split.

Reads a finished run of ``engine-gengine2`` or ``engine-gengine2-quick`` (default: the
store's latest run; run one first with ``enginebench run engine-gengine2-quick``) and, on
exactly that run's training and test records, fits scikit-learn's
``HistGradientBoostingRegressor`` with its default settings (``random_state=0``) on every
run-time input lagged by 0 to 50 s (15 evenly spaced lags, the first sample repeated before
a record's start), one model per output. Its test NRMSE is pooled over the rows the run
scores (each test record after its ``init_samples`` window), as ``enginebench``'s
``nrmse`` is. Prints per output: the naive mean, every method of the run, the best of them
and the baseline, and whether the best beats the mean and matches the baseline.

Usage: python benchmarks/gengine2_baseline.py [RUN] [--store DIR]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from enginebench.datasets import catalog
from enginebench.datasets.splits import make_splits
from enginebench.results.store import RunStore, store_root

LAG_SECONDS = 50.0
N_LAGS = 15


def lagged(U: np.ndarray, lags: np.ndarray) -> np.ndarray:
    idx = np.maximum(np.arange(len(U))[:, None] - lags[None, :], 0)
    return np.swapaxes(U[idx], 1, 2).reshape(len(U), -1)


def records(ds, names: list[str], inputs: list[str], outputs: list[str], lags: np.ndarray, skip: int = 0):
    X, Y = [], []
    for seg in names:
        frame = ds.frame[ds.frame["segment"] == seg]
        U = frame[inputs].to_numpy(dtype=float)
        X.append(lagged(U, lags)[skip:])
        Y.append(frame[outputs].to_numpy(dtype=float)[skip:])
    return np.vstack(X), np.vstack(Y)


def main() -> None:
    from sklearn.ensemble import HistGradientBoostingRegressor

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", nargs="?", default="latest")
    ap.add_argument("--store", default=None)
    args = ap.parse_args()
    run = RunStore(store_root(args.store)).get(args.run)
    config = run.config()
    ds = catalog.load(config["dataset"], variant=config.get("dataset_variant", ""))
    (split,) = make_splits(ds, **config["split"])
    outputs, inputs = list(config["targets"]), list(ds.schema.inputs)
    lags = np.unique(np.round(np.linspace(0, LAG_SECONDS / ds.dt, N_LAGS)).astype(int))
    init = int(config.get("init_samples", 0))
    Xtr, Ytr = records(split.train, split.train.segment_ids, inputs, outputs, lags)
    Xte, Yte = records(split.test, split.test.segment_ids, inputs, outputs, lags, skip=init)
    m = run.metrics()
    m = m[(m["split"] == "test") & (m["metric"] == "nrmse") & (m["status"] == "ok")]
    print(f"run {run.id}: {len(split.train.segment_ids)} training records ({len(Xtr)} rows), "
          f"{len(split.test.segment_ids)} test records ({len(Xte)} scored rows); baseline: HistGradientBoosting "
          f"defaults on {len(inputs)} inputs x lags {lags.tolist()} samples")
    print(f"{'output':12s} {'naive-mean':>10s} {'best method':>22s} {'HGB 0-50 s':>10s}  verdict   (test NRMSE, pooled)")
    for j, target in enumerate(outputs):
        t0 = time.perf_counter()
        hgb = HistGradientBoostingRegressor(random_state=0).fit(Xtr, Ytr[:, j])
        pred = hgb.predict(Xte)
        seconds = time.perf_counter() - t0
        baseline = float(np.sqrt(np.mean((pred - Yte[:, j]) ** 2)) / Yte[:, j].std())
        per = m[m["target"] == target].groupby("method")["value"].mean().sort_values()
        naive = float(per.get("naive-mean", np.nan))
        best_name = next((k for k in per.index if k != "naive-mean"), None)
        best = float(per[best_name]) if best_name else np.nan
        verdict = ("beats mean" if best < naive else "NOT below mean") + (
            ", <= HGB" if best <= baseline else f", {best / baseline - 1:+.1%} above HGB")
        print(f"{target:12s} {naive:10.4f} {f'{best_name} {best:.4f}':>22s} {baseline:10.4f}  {verdict}  "
              f"(HGB fit+predict {seconds:.1f} s)")
        print("             " + ", ".join(f"{k} {v:.4f}" for k, v in per.items()))


if __name__ == "__main__":
    main()
