"""TV derivatives: the batched ADMM solver against the ``derivative`` package's Lasso, in one process.

Both solve the same total-variation problem (``methods/numerics/derivatives.py``) on the
same windows: SINDy's settings (256-sample windows, margin 32, alpha 1e-3, time in
samples, the Lasso at tol 1e-4 and max_iter 20,000) on the standardised training
trajectories of the turboshaft data set's published split (``--size full``: 200,949 rows
of WF, 1,058 windows). The Lasso takes about 0.6 s a window, so it runs on the first
``--lasso-windows`` windows only and its time is scaled to all of them (printed as such);
ADMM runs on every window, and once more on the Lasso's windows alone. For those windows
both routes' objectives are printed, with the KKT test of each (relative violation of the
optimality conditions; the ADMM route accepts a window at <= 1e-3).

Usage: python benchmarks/tv_derivatives.py [--size full|small] [--target WF|TRQ]
       [--lasso-windows N] [--threads N]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import warnings

import numpy as np
from threadpoolctl import threadpool_limits

from enginebench.datasets import catalog
from enginebench.datasets.pools import make_samples
from enginebench.datasets.splits import make_splits
from enginebench.methods.numerics.derivatives import differentiate, window_bounds
from enginebench.methods.numerics.tv_admm import integral_matrix, kkt_violation, objective

WINDOW, MARGIN, ALPHA = 256, 32, 1e-3


def _windows(signals: list[np.ndarray]) -> np.ndarray:
    """Every full-length window SINDy's layout cuts from ``signals``, minus its first sample, as columns."""
    cols = []
    for y in signals:
        for lo, hi, _, _ in window_bounds(len(y), WINDOW, MARGIN, WINDOW - MARGIN):
            if hi - lo == WINDOW:
                cols.append(y[lo:hi] - y[lo])
    return np.array(cols).T


def _solve(B: np.ndarray, solver: str) -> np.ndarray:
    """The derivative of each column of ``B`` as one window (``differentiate`` with a window of its length)."""
    t = np.arange(B.shape[0], dtype=np.float64)
    kw = dict(window=B.shape[0], margin=0, max_iter=20_000, tol=1e-4, precompute=False, solver=solver)
    if solver == "admm":
        return differentiate(B, t, ALPHA, **kw)[1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.column_stack([differentiate(B[:, j], t, ALPHA, **kw)[1] for j in range(B.shape[1])])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="full", choices=("full", "small"))
    ap.add_argument("--target", default="WF", choices=("WF", "TRQ"))
    ap.add_argument("--lasso-windows", type=int, default=40)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    ds = catalog.load("turboshaft", variant=args.size)
    train = make_samples(make_splits(ds, kind="published")[0].train, [args.target], "simulation")
    y = np.concatenate([s.y[:, 0] for s in train.segments])
    signals = [(s.y[:, 0] - y.mean()) / y.std() for s in train.segments]
    B = _windows(signals)
    k = min(args.lasso_windows, B.shape[1])
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, {args.threads} BLAS thread(s), "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"turboshaft {args.size}, {args.target}: {len(y):,} training rows, {B.shape[1]:,} windows of {WINDOW}")
    with threadpool_limits(args.threads, user_api="blas"):
        t0 = time.perf_counter()
        _solve(B, "admm")
        t_all = time.perf_counter() - t0
        t0 = time.perf_counter()
        ours = _solve(B[:, :k], "admm")
        t_ours = time.perf_counter() - t0
        t0 = time.perf_counter()
        ref = _solve(B[:, :k], "lasso")
        t_ref = time.perf_counter() - t0
    A = integral_matrix(WINDOW, 1.0)
    f_ours, f_ref = objective(ours, B[:, :k], A, ALPHA, 1.0), objective(ref, B[:, :k], A, ALPHA, 1.0)
    v_ours, v_ref = kkt_violation(ours, B[:, :k], A, ALPHA, 1.0), kkt_violation(ref, B[:, :k], A, ALPHA, 1.0)
    print(f"ADMM, all {B.shape[1]:,} windows: {t_all:.2f} s")
    print(f"first {k} windows: ADMM {t_ours:.2f} s, Lasso {t_ref:.1f} s: ratio {t_ref / t_ours:.0f}x "
          f"(Lasso scaled to all windows: {t_ref * B.shape[1] / k:.0f} s, {t_ref * B.shape[1] / k / t_all:.0f}x)")
    print(f"objective (median over windows): ADMM {np.median(f_ours):.5g}, Lasso {np.median(f_ref):.5g} "
          f"(Lasso / ADMM: median {np.median(f_ref / f_ours):.2f}, max {np.max(f_ref / f_ours):.2f})")
    print(f"KKT violation (max over windows): ADMM {v_ours.max():.1e}, Lasso {v_ref.max():.1e}; "
          f"windows passing 1e-3: ADMM {int((v_ours <= 1e-3).sum())}/{k}, Lasso {int((v_ref <= 1e-3).sum())}/{k}")


if __name__ == "__main__":
    main()
