"""Exact KRLS model selection: our grid (at most one tridiagonalisation per gamma and fold) against
scikit-learn's GridSearchCV(KernelRidge), same folds, same grid, same criterion, one process.

    python benchmarks/krls_grid.py --n 2000 --grid 41 --folds 5
    python benchmarks/krls_grid.py --n 2000 --grid 11 --folds 5     # quick (~minutes)

Both sides select (gamma, lambda) by the mean absolute error averaged over blocked
K folds (KFold without shuffling, i.e. contiguous blocks in time order). The script
prints both wall times, their ratio, both selections, whether they agree, and the
largest relative difference between the two tables of CV scores.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
from sklearn.kernel_ridge import KernelRidge
from threadpoolctl import threadpool_limits
from sklearn.model_selection import GridSearchCV, KFold

from enginebench.method import grid_points, log_grid
from enginebench.methods.krls import KRLS
from enginebench.samples import Samples, SegmentSamples

TIE_RTOL = 1e-12


def make_problem(n: int, d: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A smooth nonlinear regression on standardised-scale inputs with noise (deterministic)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / n
    # slowly drifting inputs, so blocked folds see a little extrapolation, like time series
    X = rng.normal(size=(n, d)) + 0.5 * np.sin(2 * np.pi * np.outer(t, np.arange(1, d + 1)))
    w = rng.normal(size=d) / np.sqrt(d)
    y = np.sin(X @ w) + 0.3 * X[:, 0] * X[:, 1] + 0.2 * np.cos(X[:, 2]) ** 2 + 0.1 * rng.normal(size=n)
    return X, y


def as_samples(X: np.ndarray, y: np.ndarray, rows: np.ndarray) -> Samples:
    """One static segment holding the given rows."""
    names = tuple(f"x{j}" for j in range(X.shape[1]))
    seg = SegmentSamples(id="all", X=X[rows], rows=rows, U=X[rows], t=rows.astype(float), y=y[rows, None])
    return Samples(segments=(seg,), mode="static", window=0.0, dt=1.0, feature_names=names,
                   input_names=names, target_names=("y",))


def ours(X: np.ndarray, y: np.ndarray, gammas: np.ndarray, lambdas: np.ndarray, cv: KFold) -> np.ndarray:
    """Mean-over-folds MAE for every (gamma, lambda), shape (n_gamma, n_lambda)."""
    method = KRLS(standardize=False, center_target=False)
    grid = grid_points({"gamma": gammas, "lambda": lambdas})  # lambda varies fastest
    rng = np.random.default_rng(0)
    mae = np.zeros(len(grid))
    folds = list(cv.split(X))
    for train_rows, test_rows in folds:
        pred = method.predict_grid(as_samples(X, y, train_rows), as_samples(X, y, test_rows).without_targets(),
                                   grid, rng)
        mae += np.abs(pred[:, :, 0] - y[test_rows]).mean(axis=1)
    return (mae / len(folds)).reshape(len(gammas), len(lambdas))


def reference(X: np.ndarray, y: np.ndarray, gammas: np.ndarray, lambdas: np.ndarray, cv: KFold) -> tuple[np.ndarray, dict]:
    """GridSearchCV's mean-over-folds MAE in the same (gamma, lambda) layout, and its best_params_."""
    search = GridSearchCV(KernelRidge(kernel="rbf"), {"gamma": gammas, "alpha": lambdas}, cv=cv,
                          scoring="neg_mean_absolute_error", n_jobs=1, refit=False)
    search.fit(X, y)
    table = np.full((len(gammas), len(lambdas)), np.nan)
    gi = {float(g): i for i, g in enumerate(gammas)}
    li = {float(v): j for j, v in enumerate(lambdas)}
    for p, score in zip(search.cv_results_["params"], search.cv_results_["mean_test_score"]):
        table[gi[float(p["gamma"])], li[float(p["alpha"])]] = -score
    return table, search.best_params_


def _load() -> str:
    """The 1/5/15-minute load averages: timings on shared cores are only readable with them."""
    return "/".join(f"{v:.1f}" for v in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="number of samples")
    ap.add_argument("--d", type=int, default=8, help="number of features")
    ap.add_argument("--grid", type=int, default=11, help="values per hyperparameter (41 = krls's default grid)")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1,
                    help="BLAS threads for both sides (0 = library default); 1 keeps timings stable on shared cores")
    ap.add_argument("--skip-sklearn", action="store_true", help="time only our side")
    args = ap.parse_args()
    if args.threads > 0:
        with threadpool_limits(limits=args.threads, user_api="blas"):
            run(args)
    else:
        run(args)


def run(args: argparse.Namespace) -> None:

    X, y = make_problem(args.n, args.d, args.seed)
    gammas = log_grid(-4, 4, args.grid)
    lambdas = log_grid(-4, 4, args.grid)
    cv = KFold(n_splits=args.folds, shuffle=False)
    print(f"n={args.n} d={args.d} grid={args.grid}x{args.grid}={args.grid**2} points folds={args.folds} "
          f"(blocked KFold, no shuffle); python {platform.python_version()}, {os.cpu_count()} CPUs, "
          f"BLAS threads={args.threads or 'default'}")

    t0, c0 = time.perf_counter(), time.process_time()
    ours_mae = ours(X, y, gammas, lambdas, cv)
    t_ours, c_ours = time.perf_counter() - t0, time.process_time() - c0
    gi, li = np.unravel_index(np.argmin(ours_mae), ours_mae.shape)
    print(f"ours   : {t_ours:9.2f} s wall, {c_ours:9.2f} s CPU  load avg {_load()}  selected gamma={gammas[gi]:.4g} lambda={lambdas[li]:.4g} "
          f"CV MAE={ours_mae[gi, li]:.10g}")
    if args.skip_sklearn:
        return

    t0, c0 = time.perf_counter(), time.process_time()
    ref_mae, best = reference(X, y, gammas, lambdas, cv)
    t_ref, c_ref = time.perf_counter() - t0, time.process_time() - c0
    rg, rl = int(np.flatnonzero(gammas == best["gamma"])[0]), int(np.flatnonzero(lambdas == best["alpha"])[0])
    print(f"sklearn: {t_ref:9.2f} s wall, {c_ref:9.2f} s CPU  load avg {_load()}  selected gamma={best['gamma']:.4g} lambda={best['alpha']:.4g} "
          f"CV MAE={ref_mae[rg, rl]:.10g}")
    print(f"speed-up at n={args.n}, {args.grid}x{args.grid} grid, {args.folds} folds (sklearn / ours): "
          f"{t_ref / t_ours:.1f}x wall, {c_ref / c_ours:.1f}x CPU")
    if args.grid != 41:
        est = t_ref * 41**2 / args.grid**2
        print(f"estimate for the 41x41 grid (wall): sklearn ~{est:.0f} s ({est / 60:.1f} min, cost ~ grid points), "
              f"ours ~{t_ours * 41 / args.grid:.0f} s (cost ~ one tridiagonalisation per gamma at most)")

    rel = np.abs(ours_mae - ref_mae) / np.abs(ref_mae)
    print(f"CV score tables: max relative difference {rel.max():.2e} "
          f"(median {np.median(rel):.2e}; at the selected point {rel[gi, li]:.2e})")
    if (gi, li) == (rg, rl):
        print("selections agree: yes")
    else:
        gap = abs(ours_mae[rg, rl] - ours_mae[gi, li]) / ours_mae[gi, li]
        verdict = "a tie within 1e-12 relative" if gap <= TIE_RTOL else "NOT a tie"
        print(f"selections agree: NO - our scores at the two selections differ by {gap:.2e} relative ({verdict})")


if __name__ == "__main__":
    main()
