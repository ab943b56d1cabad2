"""TV derivatives: ``tv_solve`` with active-set refinement against the previous ADMM loop, in one process.

The previous algorithm (ADMM, every 100 iterations a polish from the signs of ``z`` and
the KKT test, no refinement; git 49614bf up to 14ce589) is kept below as ``old_tv_solve``, a
copy of its loop. Both solve the same windows: 256 samples every 192, each minus its
first sample, of standardised gengine2 columns (10 Hz: dt 0.1, alpha 1e-3, as SINDy's
gengine2 jobs; the ``nox`` column is where the old loop left 9 % of the windows open at
max_iter 20,000) and of a synthetic signal (smooth plus steps plus noise). Printed per
signal: each solver's time, the fraction of windows accepted (KKT test <= 1e-3 of alpha:
then the window is the minimiser), and on windows both accepted the largest difference
of their objectives (absolute and relative to the old objective).

The gengine2 columns need ``enginebench datasets import bosch-gengine2 --from DIR``
(``/work/shared/data/bosch-gengine2`` on the dev machine); without it they are skipped
with a message and only the synthetic signal runs.

Usage: python benchmarks/tv_active_set.py [--columns nox,t_cat] [--samples 60000]
       [--max-iter 20000] [--threads 1] [--no-synthetic]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np
from scipy.linalg import qr, solve_triangular
from threadpoolctl import threadpool_limits

from enginebench.methods.numerics import tv_admm
from enginebench.methods.numerics.tv_admm import integral_matrix, kkt_violation, objective, tv_solve

WINDOW, STEP, ALPHA, DT = 256, 192, 1e-3, 0.1
PARQUET = Path.home() / ".cache" / "enginebench" / "datasets" / "bosch-gengine2.parquet"


# --- the previous algorithm, kept verbatim as the reference (polish without refinement) ---
def _old_polish(AC: np.ndarray, b: np.ndarray, z: np.ndarray, lam: float) -> np.ndarray:
    S = np.flatnonzero(z)
    k = S.size + 1
    R = qr(np.column_stack([AC[:, np.r_[0, S + 1]], b]), mode="r", overwrite_a=True, check_finite=False)[0]
    q = np.r_[0.0, lam * np.sign(z[S])]
    theta = solve_triangular(R[:k, :k], R[:k, k] - solve_triangular(R[:k, :k], q, trans="T"))
    v = np.zeros(z.size)
    v[S] = theta[1:]
    return theta[0] + np.r_[0.0, np.cumsum(v)]


def old_tv_solve(B: np.ndarray, alpha: float, dt: float = 1.0, *, max_iter: int = 20_000, tol: float = 1e-3):
    B = np.asarray(B, dtype=np.float64)
    n, W = B.shape
    lam = alpha / dt
    A = integral_matrix(n, dt)
    AC = np.cumsum(A[:, ::-1], axis=1)[:, ::-1]
    rho = tv_admm.RHO_PER_ALPHA * lam
    D = np.diff(np.eye(n), axis=0)
    Minv = np.linalg.inv(A.T @ A + rho * (D.T @ D))
    AtB = A.T @ B
    out = np.empty_like(B)
    done = np.zeros(W, dtype=bool)
    open_ = np.arange(W)
    Z = np.zeros((n - 1, W))
    Y = np.zeros((n - 1, W))
    tried = np.full((n - 1, W), 2, dtype=np.int8)
    for it in range(1, max_iter + 1):
        R = Z - Y
        DtR = np.zeros((n, R.shape[1]))
        DtR[:-1] -= R
        DtR[1:] += R
        U = Minv @ (AtB + rho * DtR)
        DU = np.diff(U, axis=0)
        V = DU + Y
        Z = np.sign(V) * np.maximum(np.abs(V) - lam / rho, 0.0)
        Y += DU - Z
        last = it == max_iter
        if it % tv_admm.ROUND and not last:
            continue
        signs = np.sign(Z).astype(np.int8)
        new = np.flatnonzero((signs != tried).any(axis=0) | last)
        tried[:, new] = signs[:, new]
        P = np.column_stack([_old_polish(AC, B[:, j], Z[:, j], lam) for j in new]) if new.size else np.empty((n, 0))
        ok = np.zeros(open_.size, dtype=bool)
        ok[new] = kkt_violation(P, B[:, new], A, alpha, dt) <= tol
        out[:, open_[ok]] = P[:, ok[new]]
        done[open_[ok]] = True
        if last:
            keep = ~ok
            better = objective(P[:, keep], B[:, keep], A, alpha, dt) < objective(U[:, keep], B[:, keep], A, alpha, dt)
            out[:, open_[keep]] = np.where(better, P[:, keep], U[:, keep])
            break
        if ok.all():
            break
        keep = ~ok
        open_, B, AtB, Z, Y, tried = open_[keep], B[:, keep], AtB[:, keep], Z[:, keep], Y[:, keep], tried[:, keep]
    return out, done
# --- end of the previous algorithm ---


def windows(y: np.ndarray) -> np.ndarray:
    """Windows of WINDOW samples every STEP of the standardised ``y``, each minus its first sample, as columns."""
    y = (y - y.mean()) / y.std()
    return np.stack([y[i : i + WINDOW] - y[i] for i in range(0, len(y) - WINDOW + 1, STEP)], axis=1)


def synthetic(samples: int, seed: int = 0) -> np.ndarray:
    """Smooth oscillations, random steps and ramps, and 2 % noise at 10 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(samples) * DT
    y = np.sin(0.05 * t) + 0.5 * np.sin(0.31 * t + 1.0)
    y += np.cumsum(rng.standard_normal(samples) * (rng.random(samples) < 0.01))  # steps
    y += 0.02 * np.cumsum(np.where(rng.random(samples) < 0.002, rng.standard_normal(samples), 0.0)) * t / t[-1]
    return y + 0.02 * rng.standard_normal(samples)


def compare(name: str, B: np.ndarray, max_iter: int) -> None:
    A = integral_matrix(B.shape[0], DT)
    t0 = time.perf_counter()
    U_old, ok_old = old_tv_solve(B, ALPHA, DT, max_iter=max_iter)
    t_old = time.perf_counter() - t0
    t0 = time.perf_counter()
    U_new, ok_new = tv_solve(B, ALPHA, DT, max_iter=max_iter)
    t_new = time.perf_counter() - t0
    both = ok_old & ok_new
    f_old, f_new = objective(U_old, B, A, ALPHA, DT), objective(U_new, B, A, ALPHA, DT)
    diff = np.abs(f_new - f_old)[both]
    rel = (diff / np.abs(f_old[both])) if both.any() else diff
    k_new = kkt_violation(U_new[:, ok_new], B[:, ok_new], A, ALPHA, DT).max(initial=0.0)
    print(f"{name}: {B.shape[1]} windows of {B.shape[0]}")
    print(f"  old loop : {t_old:7.2f} s, accepted {ok_old.mean():6.1%} ({ok_old.sum()})")
    print(f"  tv_solve : {t_new:7.2f} s, accepted {ok_new.mean():6.1%} ({ok_new.sum()}), "
          f"largest KKT violation of accepted {k_new:.1e}")
    print(f"  ratio old/new {t_old / t_new:.1f}x; on {both.sum()} windows both accepted the objectives differ "
          f"by at most {diff.max(initial=0.0):.2e} ({rel.max(initial=0.0):.1e} relative)")
    if (~ok_old & ok_new).any():
        gain = (f_old - f_new)[~ok_old & ok_new]
        print(f"  windows only tv_solve accepted: {gain.size}, old objective higher by at most {gain.max():.2e}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--columns", default="nox,t_cat", help="gengine2 columns, comma-separated")
    ap.add_argument("--samples", type=int, default=60_000, help="first samples of each column")
    ap.add_argument("--max-iter", type=int, default=20_000)
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads")
    ap.add_argument("--no-synthetic", action="store_true")
    args = ap.parse_args(argv)
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}, "
          f"{args.threads} BLAS thread(s); alpha {ALPHA}, dt {DT}, max_iter {args.max_iter}")
    with threadpool_limits(args.threads):
        if PARQUET.exists():
            import pandas as pd

            df = pd.read_parquet(PARQUET)
            for col in args.columns.split(","):
                compare(f"gengine2 {col}", windows(df[col].to_numpy(dtype=np.float64)[: args.samples]), args.max_iter)
        else:
            print(f"skipped gengine2: {PARQUET} is absent (make it with `enginebench datasets import "
                  "bosch-gengine2 --from /work/shared/data/bosch-gengine2`)")
        if not args.no_synthetic:
            compare("synthetic", windows(synthetic(args.samples)), args.max_iter)


if __name__ == "__main__":
    main()
