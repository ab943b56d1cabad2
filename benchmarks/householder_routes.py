"""The Householder route's two ways for many shifts, timed in one process: one tridiagonal solve per
distinct shift against one eigendecomposition of T (filters in its eigenbasis).

Both give sum_r w_jr K_eval (K + mu_jr I)^-1 b for J grid points with two shifts each (MTL-KRLS's
shape) from the same tridiagonalisation; the script prints both times, their agreement and where
the eigenbasis starts to pay, which sets ``SPECTRAL_SHIFTS_PER_ROW`` in methods/numerics/shifted.py.

    python benchmarks/householder_routes.py --threads 1
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from threadpoolctl import threadpool_limits

from enginebench.methods.numerics import shifted
from enginebench.methods.numerics.kernels import gaussian, sq_distances


def best_time(H: shifted._Householder, b: np.ndarray, shifts: np.ndarray, weights: np.ndarray, K_eval: np.ndarray,
              per_row: float, repeat: int) -> tuple[float, np.ndarray]:
    """Fastest of ``repeat`` calls of the route that ``per_row`` selects (T's spectrum recomputed each time)."""
    saved = shifted.SPECTRAL_SHIFTS_PER_ROW
    shifted.SPECTRAL_SHIFTS_PER_ROW = per_row
    try:
        best, out = float("inf"), None
        for _ in range(repeat):
            H._spectrum = None
            t0 = time.perf_counter()
            out = H.combinations(b, shifts, weights, K_eval)
            best = min(best, time.perf_counter() - t0)
        return best, out
    finally:
        shifted.SPECTRAL_SHIFTS_PER_ROW = saved


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="632,1000,1600", help="kernel rows n, comma-separated")
    ap.add_argument("--m", type=int, default=400, help="evaluation rows")
    ap.add_argument("--per-row", default="0.25,0.5,1,2,4", help="distinct shifts per kernel row")
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads (a run's worker has 1)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    print(f"BLAS threads {args.threads}, {args.m} evaluation rows, best of {args.repeat}")
    with threadpool_limits(args.threads, "blas"):
        for n in (int(v) for v in args.sizes.split(",")):
            X = rng.uniform(-2, 2, (n + args.m, 7))
            K, K_eval = gaussian(sq_distances(X[:n]), 0.1), gaussian(sq_distances(X[n:], X[:n]), 0.1)
            b = rng.normal(size=(n, 1))
            H = shifted._Householder(K, overwrite=True)
            for frac in (float(v) for v in args.per_row.split(",")):
                J = max(1, int(frac * n / 2))
                shifts, weights = 10.0 ** rng.uniform(-8, 4, (J, 2)), rng.uniform(0, 1, (J, 2))
                t_solve, p_solve = best_time(H, b, shifts, weights, K_eval, float("inf"), args.repeat)
                t_eig, p_eig = best_time(H, b, shifts, weights, K_eval, 0.0, args.repeat)
                diff = np.abs(p_solve - p_eig).max() / np.abs(p_solve).max()
                print(f"n = {n:5d}, {2 * J:6d} distinct shifts ({2 * J / n:4.2f} n): solves {t_solve * 1e3:7.1f} ms, "
                      f"eigenbasis {t_eig * 1e3:7.1f} ms, ratio {t_solve / t_eig:4.2f}; max relative difference {diff:.1e}",
                      flush=True)
    print("load avg " + "/".join(f"{v:.1f}" for v in os.getloadavg()))


if __name__ == "__main__":
    main()
