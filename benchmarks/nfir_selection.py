"""NFIR model selection: the shared-work grid path against the eigendecomposition path it replaced, one process.

    python benchmarks/nfir_selection.py                       # 1,024- and 4,096-sample records, 5 folds
    python benchmarks/nfir_selection.py --samples 1024 --folds 2 --repeats 3

A tanks-like record (``short_record_selection.simulate``: two cascaded tanks, dt = 4 s, 1 % output
noise) is the training set of ``select`` with NFIR's defaults (horizons derived from the data's memory,
5 gammas x 9 lambdas, at most 1,000 kernel rows, the grid-edge extension), blocked k-fold in simulation
mode with a 50-sample init window: what ``enginebench run`` does for one job. The same selection is run
twice on the same data with the same generator: once with ``NFIR.predict_grid`` (per lag set the
distances once, per gamma ``ridge_solutions``: certified shifted Lanczos, Cholesky or one Householder
tridiagonalisation, ``methods/numerics/kernel_grid.py``) and once with the path it replaced (per gamma
one eigendecomposition of the training kernel, evaluation distances per gamma), kept below as
:func:`reference_predict_grid`. It prints both wall times (best of ``--repeats``), their ratio, both
selections, the largest difference between the two score tables and, on the first fold, between the two
grids of predictions (relative to the output's standard deviation; overall and per lambda), and what the
memory estimate costs.

Both paths are exact to rounding; the penalty lambda bounds how much rounding the solve amplifies (the
condition number of K + lambda I is up to n / lambda), so at lambda = 1e-8 any two exact solvers
(eigendecomposition, tridiagonalisation, Cholesky) differ by ~1e-5 of the output's scale and at
lambda >= 1e-3 by ~1e-10 or less; the picks are the same.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.experiments.selection import record_blocks, select
from enginebench.experiments.spec import Selection
from enginebench.method import Params, grid_points
from enginebench.methods.krls import KRLS
from enginebench.methods.nfir import NFIR, PREDICT_CHUNK
from enginebench.methods.numerics.kernels import Spectral, gaussian, sq_distances
from enginebench.samples import Samples

sys.path.insert(0, str(Path(__file__).resolve().parent))
from short_record_selection import simulate  # noqa: E402  (the tanks-like generator, a sibling script)

DT = 4.0
INIT = 50


def reference_predict_grid(method: NFIR, train: Samples, data: Samples, grid: Sequence[Params],
                           rng: np.random.Generator) -> np.ndarray:
    """The path before: per lag set one scaling, per gamma one eigendecomposition, eval distances per gamma."""
    k_out = len(train.target_names)
    out = np.empty((len(grid), len(data), k_out))
    for members, sub, evaluated, gammas, lambdas in method.lag_groups(train, data, grid, rng):
        scaler, Xs, yc, y_mean, y_scale = KRLS._train_arrays(method, sub)
        Xe = scaler.transform(evaluated.X)
        D_train = sq_distances(Xs)
        for gamma in dict.fromkeys(gammas.tolist()):
            idx = np.flatnonzero(gammas == gamma)
            spectral = Spectral.from_kernel(gaussian(D_train, gamma), overwrite=True)
            alpha = spectral.lift(spectral.ridge_coeffs(spectral.project(yc), lambdas[idx])).reshape(len(Xs), -1)
            target = np.asarray(members)[idx]
            for a in range(0, len(Xe), PREDICT_CHUNK):
                K = gaussian(sq_distances(Xe[a:a + PREDICT_CHUNK], Xs), gamma)
                block = (K @ alpha).reshape(len(K), len(idx), k_out)
                out[target, a:a + PREDICT_CHUNK] = np.moveaxis(block, 1, 0) * y_scale + y_mean
    return out


class ReferenceNFIR(NFIR):
    """NFIR with the eigendecomposition grid path (the reference of this benchmark)."""

    def predict_grid(self, train: Samples, data: Samples, grid: Sequence[Params],
                     rng: np.random.Generator) -> np.ndarray:
        return reference_predict_grid(self, train, data, grid, rng)


def tanks_record(samples: int, seed: int) -> Samples:
    """One simulated tanks-like record of ``samples`` samples as training samples (simulation mode)."""
    u, y = simulate(np.random.default_rng(seed), n=samples, dt=DT)
    frame = pd.DataFrame({"segment": "estimation", "time": np.arange(samples) * DT, "u": u, "y": y})
    return make_samples(Dataset("tanks-like", frame, Schema.from_roles({"u": "input", "y": "output"}), DT),
                        ["y"], "simulation")


def timed_select(method: NFIR, train: Samples, selection: Selection, seed: int, repeats: int
                 ) -> tuple[float, Params, dict]:
    """Best wall time of ``repeats`` selections (memory estimate cached first), the pick and its record."""
    method.memory(train)
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        chosen, record = select(method, train, selection, np.random.default_rng(seed), init_samples=INIT)
        best = min(best, time.perf_counter() - start)
    return best, chosen, record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, nargs="+", default=[1024, 4096])
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="BLAS threads (default 1: one core, stable timings)")
    args = parser.parse_args()
    print(f"{platform.processor() or platform.machine()}, {args.threads} BLAS thread(s), {args.folds}-fold "
          f"selection, best of {args.repeats}")
    selection = Selection(kind="kfold", folds=args.folds, criterion="rmse")
    with threadpool_limits(limits=args.threads):
        for samples in args.samples:
            train = tanks_record(samples, args.seed)
            new, old = NFIR(), ReferenceNFIR()
            start = time.perf_counter()
            memory = NFIR().memory(train)
            t_memory = time.perf_counter() - start
            t_old, pick_old, rec_old = timed_select(old, train, selection, args.seed, args.repeats)
            t_new, pick_new, rec_new = timed_select(new, train, selection, args.seed, args.repeats)
            same_pick = pick_old.keys() == pick_new.keys() and all(
                np.isclose(float(pick_old[k]), float(pick_new[k]), rtol=1e-12, atol=0) for k in pick_old)
            s_old, s_new = rec_old["table"].scores, rec_new["table"].scores
            score_diff = (float(np.max(np.abs(s_old - s_new) / np.abs(s_old)))
                          if s_old.shape == s_new.shape else float("nan"))
            fit, val = record_blocks(train.segment_sizes, args.folds, INIT)[0]
            fit_part, val_part = train.cut(fit), train.cut(val, INIT).without_targets()
            grid = grid_points(new.search_space(train))
            p_new = new.predict_grid(fit_part, val_part, grid, np.random.default_rng(args.seed))
            p_old = old.predict_grid(fit_part, val_part, grid, np.random.default_rng(args.seed))
            pred_diff = float(np.max(np.abs(p_new - p_old)) / np.std(train.y))
            lams = np.array([float(p["lambda"]) for p in grid])
            by_lambda = ", ".join(f"{lam:.0e} {np.max(np.abs(p_new - p_old)[lams == lam]) / np.std(train.y):.1e}"
                                  for lam in np.unique(lams))
            print(f"\n{samples}-sample record: horizons {list(memory.grid)} samples, {len(grid)} grid points, "
                  f"{rec_new['resamples']} folds, {rec_new.get('extension_points', 0)} extension points")
            print(f"  memory estimate        {t_memory:8.3f} s (once per training set)")
            print(f"  eigendecomposition     {t_old:8.3f} s   pick {({k: float(v) for k, v in pick_old.items()})}")
            print(f"  shared-work path       {t_new:8.3f} s   pick {({k: float(v) for k, v in pick_new.items()})}")
            print(f"  ratio (old / new)      {t_old / t_new:8.2f} x   same pick: {same_pick}")
            print(f"  max relative score difference {score_diff:.2e}; max prediction difference on fold 1 "
                  f"{pred_diff:.2e} of the output's std")
            print(f"  ... per lambda (rounding amplified like 1 / lambda, the same between any two exact solvers): "
                  f"{by_lambda}")


if __name__ == "__main__":
    main()
