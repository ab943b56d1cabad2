"""How low can a simulation model go on Silverbox's first 32,000 test samples? (issue 30)

Reads the test predictions of a stored ``silverbox`` run (``enginebench run silverbox
--methods narx,poly-narx``; any methods) and prints, for each method, what its free-run error
on the first 32,000 evaluated samples of the 'arrow' is made of:

- the RMSE per block of 4,000 samples next to the output's amplitude (standard deviation) in
  that block: an error that stays the same while the amplitude grows tenfold is not a model's
  nonlinearity error (which grows with the amplitude) but a disturbance the input does not carry;
- the error's mean (an offset between estimation and test parts no input explains) and its
  standard deviation;
- a held-out check that the error is not a linear function of the measured input: a 64-lag FIR
  from the input to the error fitted on the first half of the samples and applied to the
  second; when it leaves the second half's error as large or larger, no linear dynamics the
  models missed is left in it;
- the correlation between every two methods' errors: methods of different classes making the
  same error point at the data, not at the models.

The input is read from the imported dataset (``enginebench datasets import silverbox --from
DIR``; ``ENGINEBENCH_DATA`` picks the data home).

Usage: python benchmarks/silverbox_floor.py RUN [--store DIR] [--samples 32000] [--block 4000]
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np
from enginebench.api import open_run
from enginebench.datasets import catalog
from enginebench.errors import EngineBenchError

FIR_LAGS = 64


def _input_before(u: np.ndarray, start: int, n: int) -> np.ndarray:
    """Rows t = start .. start+n-1 of the input's last ``FIR_LAGS`` samples (u(t), u(t-1), ...)."""
    return np.column_stack([u[start - i:start + n - i] for i in range(FIR_LAGS)])


def _fir_holdout(err: np.ndarray, lagged_u: np.ndarray) -> tuple[float, float]:
    """(second half's error std, the same after subtracting a FIR fitted to the first half)."""
    half = len(err) // 2
    coef, *_ = np.linalg.lstsq(lagged_u[:half], err[:half], rcond=None)
    return float(err[half:].std()), float((err[half:] - lagged_u[half:] @ coef).std())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", help="run id or folder of a silverbox run")
    parser.add_argument("--store", default=None, help="the run store (default: the current one)")
    parser.add_argument("--samples", type=int, default=32000, help="evaluated samples looked at (default 32000)")
    parser.add_argument("--block", type=int, default=4000, help="block length for error vs amplitude (default 4000)")
    args = parser.parse_args()

    try:
        run = open_run(args.run, store=args.store)
        data = catalog.load("silverbox", columns=["V1", "V2"]).frame
    except EngineBenchError as exc:  # a run or dataset not found: one line, exit 2 as the CLI does
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    u_all = data["V1"].to_numpy()
    y_all = data["V2"].to_numpy()

    errors: dict[str, np.ndarray] = {}
    truth = None
    start = None
    jobs = run.jobs()
    for method in jobs.loc[(jobs["target"] == "V2") & (jobs["status"] == "ok"), "method"].unique():
        if method == "naive-mean":
            continue
        print(f"re-fitting {method} with its selected hyperparameters to predict the test part ...", flush=True)
        pred = run.predictions(method, "V2")
        t = pred["truth"].to_numpy()[:args.samples]
        if truth is None:
            truth = t
            start = _locate(y_all, t)
        errors[method] = pred["prediction"].to_numpy()[:args.samples] - t
    if truth is None or start is None:
        print("error: no test predictions of V2 in this run: run `enginebench run silverbox` first", file=sys.stderr)
        raise SystemExit(2)
    lagged_u = _input_before(u_all, start, len(truth))

    print(f"Silverbox, first {len(truth)} evaluated test samples (dataset rows {start}..{start + len(truth) - 1})")
    print("block rows        amplitude [mV]  " + "  ".join(f"{m:>10}" for m in errors) + "   (error RMSE [mV])")
    for lo in range(0, len(truth), args.block):
        hi = min(lo + args.block, len(truth))
        row = "  ".join(f"{1e3 * np.sqrt(np.mean(e[lo:hi] ** 2)):10.4f}" for e in errors.values())
        print(f"{lo:6d}..{hi - 1:<6d}   {1e3 * truth[lo:hi].std():14.2f}  {row}")
    for method, e in errors.items():
        before, after = _fir_holdout(e, lagged_u)
        print(f"{method}: RMSE {1e3 * np.sqrt(np.mean(e ** 2)):.4f} mV = mean {1e3 * e.mean():+.4f} mV and std "
              f"{1e3 * e.std():.4f} mV; a {FIR_LAGS}-lag FIR from the input fitted on the first half leaves the "
              f"second half's error std {1e3 * before:.4f} -> {1e3 * after:.4f} mV")
    for (a, ea), (b, eb) in itertools.combinations(errors.items(), 2):
        print(f"correlation of the errors of {a} and {b}: {np.corrcoef(ea, eb)[0, 1]:.3f}")


def _locate(y_all: np.ndarray, truth: np.ndarray) -> int | None:
    """The dataset row where the scored test samples start (the truth column equals the dataset's V2 there)."""
    head = truth[:200]
    hits = np.flatnonzero(np.isclose(y_all[: len(y_all) - len(head)], head[0], rtol=0, atol=1e-15))
    for i in hits:
        if np.array_equal(y_all[i:i + len(head)], head):
            return int(i)
    return None


if __name__ == "__main__":
    main()
