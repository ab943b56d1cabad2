"""SINDy's model selection on the real engine campaign: the path before (issue 29) against now, in one process.

One output of ``engine-gengine2`` (``bosch-gengine2``'s training records, 10 Hz), selected as the
experiment does: 3-fold k-fold inside the records (``record_blocks``), then the final fit on
all training records. Two costs are timed on the same data, old against new:

- derivatives: ``derivative_scale = "training"`` (each fold's training set differentiated
  afresh, standardised by its own statistics) against ``"segment"`` (each record or piece
  standardised by itself and differentiated once per process: the folds' shared records and
  the final fit read the cache). Default TV derivatives (batched ADMM).
- STLSQ fits of the grid's models on fold 1's training set (derivatives prepared before):
  pysindy on every sample for every fit (``stlsq = "pysindy"``) against the library's Gram
  matrix formed once per order and degree (``stlsq = "gram"``), order 1 and order 2 grids.
- free runs of the grid's models on fold 1's validation block: one model at a time through
  ``simulate_batch`` (as ``Method.predict_grid`` did, calling ``predict`` per model) against
  ``SINDy.predict_grid``'s one time loop for every model (``simulate_candidates``); the largest
  relative difference between the two is printed (the grid's order-1 models, fitted once).

Usage: python benchmarks/sindy_speed.py [--target t_cat] [--rows N] [--candidates N]
       [--phases derivatives,fits,free-runs]
(``--rows`` keeps the first N rows of every record for a quick run; ``--candidates`` times the
old one-by-one free runs on the first N models only and scales their time to the grid.)
Import the data first: ``enginebench datasets import bosch-gengine2 --from DIR``.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from enginebench.datasets import catalog
from enginebench.datasets.pools import make_samples
from enginebench.datasets.splits import make_splits
from enginebench.experiments.selection import record_blocks
from enginebench.method import grid_points
from enginebench.methods import sindy as sindy_module
from enginebench.methods.sindy import SINDy, initial_state
from enginebench.methods.sindy_grid import clear_segment_cache
from enginebench.methods.sindy_library import simulate_batch

FOLDS, INIT = 3, 50


def _one_by_one(m: SINDy, fits: list, data) -> np.ndarray:
    """The former ``predict`` per model: ``simulate_batch`` over the segments, one model at a time."""
    out = []
    for f in fits:
        x0, controls, times, starts = [], [], [], []
        for s in data.segments:
            start, y = initial_state(s)
            starts.append(start)
            x0.append((y - f.state_mean) / f.state_std)
            controls.append((s.U[start:] - f.control_mean) / f.control_std)
            times.append(s.t[start:] / f.time_scale)
        trajs, _ = simulate_batch(f.coef, f.powers, np.vstack(x0), controls, times, f.lower, f.upper,
                                  integrator=m.options["integrator"], substeps=int(m.options["substeps"]))
        out.append(np.concatenate([(tr * f.state_std + f.state_mean)[np.asarray(s.rows) - a]
                                   for tr, s, a in zip(trajs, data.segments, starts)]))
    return np.stack(out)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", default="t_cat")
    ap.add_argument("--rows", type=int, default=0)
    ap.add_argument("--candidates", type=int, default=0)
    ap.add_argument("--phases", default="derivatives,fits,free-runs")
    args = ap.parse_args(argv)
    ds = catalog.load("bosch-gengine2")
    train = make_samples(make_splits(ds, kind="published")[0].train, [args.target], "simulation")
    if args.rows:
        train = train.cut([(k, 0, min(n, args.rows)) for k, n in enumerate(train.segment_sizes)])
    parts = [(train.cut(fit), train.cut(val, INIT)) for fit, val in record_blocks(train.segment_sizes, FOLDS, INIT)]
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"bosch-gengine2 {args.target}: {len(train):,} training rows in {len(train.segments)} records; "
          f"{FOLDS} folds fit on {', '.join(f'{len(f):,}' for f, _ in parts)} rows, validate on "
          f"{', '.join(f'{len(v):,}' for _, v in parts)}")

    phases = set(args.phases.split(","))
    times = {}
    for scale in ("training", "segment") if "derivatives" in phases else ():
        sindy_module._prepared.clear()
        clear_segment_cache()
        m = SINDy(derivative_scale=scale)
        t0 = time.perf_counter()
        for fit, _ in parts:
            m._prepare(fit)
        m._prepare(train)
        times[scale] = time.perf_counter() - t0
        print(f"derivatives, 3 folds + final fit, derivative_scale={scale!r}: {times[scale]:.1f} s")
    if times:
        print(f"derivatives: {times['training'] / times['segment']:.2f}x faster")

    fit, val = parts[0]
    if "fits" in phases:
        for order in (1, 2):
            grid = [p for p in grid_points(SINDy().search_space(train)) if p["order"] == order]
            took = {}
            for route in ("pysindy", "gram"):
                m = SINDy(stlsq=route)
                prep = m._prepare(fit)
                if order == 2:
                    m._second_order(prep)
                prep.memo.clear() if route == "gram" else None  # the Gram matrices are part of the timed work
                if order == 2:
                    m._second_order(prep)
                t0 = time.perf_counter()
                coefs = [m._fit_prepared(prep, fit, p).coef for p in grid]
                took[route] = time.perf_counter() - t0
                if route == "pysindy":
                    ref = coefs
            same = sum(np.array_equal(a != 0, b != 0) for a, b in zip(coefs, ref))
            worst = max(float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)) for a, b in zip(coefs, ref))
            print(f"STLSQ fits of the {len(grid)} order-{order} grid points on {len(fit):,} rows: pysindy "
                  f"{took['pysindy']:.1f} s, Gram {took['gram']:.1f} s: {took['pysindy'] / took['gram']:.1f}x faster; "
                  f"same terms in {same}/{len(grid)}, largest coefficient difference {worst:.1e} of the largest")
    if "free-runs" not in phases:
        return
    m = SINDy()
    grid = [p for p in grid_points(m.search_space(train)) if p["order"] == 1]
    fits = [f for _, f in sorted(m.fit_grid(fit, grid, np.random.default_rng(0)), key=lambda x: x[0])]
    view = val.without_targets()
    n_old = args.candidates or len(fits)
    t0 = time.perf_counter()
    old = _one_by_one(m, fits[:n_old], view)
    t_old = (time.perf_counter() - t0) * len(fits) / n_old
    t0 = time.perf_counter()
    new = m._simulate(fits, view)[0]
    t_new = time.perf_counter() - t0
    new = np.stack([np.concatenate(a) for a in new])
    rel = np.abs(new[:n_old] - old) / np.maximum(np.abs(old), 1e-300)
    scaled = f" (timed on {n_old}, scaled)" if n_old < len(fits) else ""
    print(f"free runs of {len(fits)} order-1 models on {len(val):,} validation rows ({len(val.segments)} blocks): "
          f"one by one {t_old:.1f} s{scaled}, one loop {t_new:.1f} s: {t_old / t_new:.1f}x faster; "
          f"largest relative difference {np.nanmax(rel):.1e}")


if __name__ == "__main__":
    main()
