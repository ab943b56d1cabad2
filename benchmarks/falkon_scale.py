"""FALKON at scale: time, peak memory, CG iterations and test MAE on a seeded synthetic problem.

    python benchmarks/falkon_scale.py --n 1000000 --d 40 --centres 2000 --device auto
    python benchmarks/falkon_scale.py --n 100000  --d 40 --centres 2000 --threads 1

The problem is a smooth nonlinear regression on standard-normal inputs with Gaussian
noise (sd 0.1); the test set is 10,000 fresh rows of the same distribution. Besides the
fit and predict wall times the script prints the reference points that make the MAE
readable: the noise floor (the MAE of the noiseless truth, 0.1 * sqrt(2/pi)) and the MAE
of the training mean. Peak memory is the process's ru_maxrss (it includes the data,
~n*d*8 bytes, and the Python/torch baseline) or, on CUDA, torch.cuda.max_memory_allocated.
Timings on a shared machine are pessimistic: the script prints the load average.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import time

import numpy as np
import torch

from enginebench.methods.numerics.falkon import FalkonSolver

NOISE_SD = 0.1
N_TEST = 10_000


def make_problem(n: int, d: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(X, y) for training and (X_test, y_test), deterministic given the seed."""
    rng = np.random.default_rng(seed)
    w = rng.normal(size=d) / np.sqrt(d)
    v = rng.normal(size=d) / np.sqrt(d)

    def draw(rows: int) -> tuple[np.ndarray, np.ndarray]:
        X = rng.normal(size=(rows, d))
        y = np.sin(X @ w) + 0.5 * np.tanh(X @ v) * X[:, 0] + 0.2 * np.cos(X[:, 1]) + NOISE_SD * rng.normal(size=rows)
        return X, y[:, None]

    X, y = draw(n)
    X_test, y_test = draw(N_TEST)
    return X, y, X_test, y_test


def peak_memory_gib(device: str) -> tuple[float, str]:
    """Peak memory of this process in GiB, and what was measured."""
    if device.startswith("cuda"):
        return torch.cuda.max_memory_allocated() / 2**30, "torch.cuda.max_memory_allocated"
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, "ru_maxrss (whole process, data included)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=1_000_000, help="training rows")
    parser.add_argument("--d", type=int, default=40, help="features")
    parser.add_argument("--centres", type=int, default=2000, help="Nystroem centres m")
    parser.add_argument("--device", default="auto", help="auto, cpu or cuda[:i]")
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                        help="precision of the streamed kernel blocks (the CG algebra is always float64)")
    parser.add_argument("--gamma", type=float, default=None, help="kernel width; default 1/(4d)")
    parser.add_argument("--lam-per-row", type=float, default=1e-5,
                        help="lambda / n (the exact solver's lambda is this times n)")
    parser.add_argument("--maxiter", type=int, default=30)
    parser.add_argument("--tol", type=float, default=1e-5, help="CG stopping rule on the relative residual")
    parser.add_argument("--block-mib", type=float, default=4.0, help="memory of one streamed kernel block (cache-sized)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    gamma = args.gamma if args.gamma is not None else 1.0 / (4 * args.d)
    lam = args.lam_per_row * args.n

    t0 = time.perf_counter()
    X, y, X_test, y_test = make_problem(args.n, args.d, args.seed)
    t_data = time.perf_counter() - t0

    solver = FalkonSolver(gamma, lam, centres=args.centres, maxiter=args.maxiter, tol=args.tol,
                          device=args.device, dtype=getattr(torch, args.dtype), block_mib=args.block_mib)
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    solver.fit(X, y, np.random.default_rng(args.seed + 1))
    if solver.device.type == "cuda":
        torch.cuda.synchronize()
    t_fit = time.perf_counter() - t0
    t0 = time.perf_counter()
    pred = solver.predict(X_test)
    t_predict = time.perf_counter() - t0

    mae = float(np.abs(pred - y_test).mean())
    mae_mean = float(np.abs(y.mean() - y_test).mean())
    peak, how = peak_memory_gib(str(solver.device))
    info = solver.info
    print(f"n={args.n} d={args.d} centres={info['centres']} device={info['device']} dtype={info['dtype']} "
          f"threads={torch.get_num_threads()} cpus={os.cpu_count()} load_avg={os.getloadavg()[0]:.1f} "
          f"({platform.processor() or platform.machine()}, torch {torch.__version__})")
    print(f"gamma={gamma:.4g} lambda={lam:.4g} (lambda/n={args.lam_per_row:.3g}) "
          f"blocks={info['blocks']} x {info['block_rows']} rows, cached={info['cached']}")
    print(f"data generation {t_data:.1f} s")
    print(f"load average before the fit {'/'.join(f'{v:.1f}' for v in load_before)}, "
          f"after {'/'.join(f'{v:.1f}' for v in os.getloadavg())}")
    print(f"fit {t_fit:.1f} s: {info['iterations']} CG iterations ({info['passes']} passes over the data, "
          f"{t_fit / info['passes']:.2f} s per pass), relative residual {info['residual']:.2e}, "
          f"converged={info['converged']}")
    print(f"predict {N_TEST} rows {t_predict:.2f} s")
    print(f"test MAE {mae:.4f} (noise floor {NOISE_SD * np.sqrt(2 / np.pi):.4f}, training-mean MAE {mae_mean:.4f})")
    print(f"peak memory {peak:.2f} GiB [{how}]")


if __name__ == "__main__":
    main()
