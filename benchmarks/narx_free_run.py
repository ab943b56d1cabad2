"""narx's batched free run over a selection grid: one input product per draw of centres against one per model.

narx's selection simulates every grid candidate at once (``narx_model.free_run``). The candidates of one lag
order share a draw of Nystroem centres and differ in gamma and lambda, so the input part of each step's
exponent (inputs' lags against the centres, a matrix product over every step of a block) is the same for them
up to the scale gamma / d: it is computed once per draw and scaled. The reference is the same free run with
each candidate holding its own copy of the centres (one product per model, as before), in the same process;
the largest relative difference of the simulated outputs is printed with the CPU times and their ratio.

The grid is narx's default shape on a campaign: lags {2, 4, 8, 16, 32, 64} (the kernel reads at most 8), 4
gammas x 5 lambdas, 500 centres, 5 inputs, two segments of ``--steps`` samples (made-up stable models:
the timing depends on the sizes, not on the values).

Usage: python benchmarks/narx_free_run.py [--steps 4000] [--repeat 2]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from enginebench.methods.narx_model import KernelModel, free_run


def grid_models(rng: np.random.Generator, inputs: int, centres: int) -> list[KernelModel]:
    models = []
    for na in (2, 4, 8, 16, 32, 64):
        ka = kb = min(na, 8)
        C = rng.normal(size=(centres, ka + inputs * kb))  # one draw per lag order, shared by its candidates
        for gamma in (1e-3, 1e-2, 1e-1, 1.0):
            for lam in (1e-12, 1e-10, 1e-8, 1e-6, 1e-4):
                models.append(KernelModel(na=na, nb=na, nk=0, ka=ka, kb=kb, a=rng.normal(size=na) * 0.3 / na,
                                          b=rng.normal(size=(inputs, na)) * 0.01, c0=0.0, centres=C,
                                          beta=rng.normal(size=centres) * 0.01, gamma=gamma, lam=lam, target=0))
    return models


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=4000, help="samples per segment (two segments)")
    ap.add_argument("--repeat", type=int, default=2, help="timings per path (the best is kept)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    inputs, centres = 5, 500
    shared = grid_models(rng, inputs, centres)
    own = [replace(m, centres=m.centres.copy()) for m in shared]
    U = [rng.normal(size=(args.steps, inputs)) for _ in range(2)]
    W = [rng.normal(size=(50, 1)) for _ in range(2)]
    lengths = [args.steps, args.steps - 7]
    best = {}
    runs = {}
    for _ in range(args.repeat):
        for name, models in (("one product per model (reference)", own), ("one per draw of centres", shared)):
            t = time.process_time()
            runs[name] = free_run(models, U, W, lengths)
            best[name] = min(best.get(name, np.inf), time.process_time() - t)
    ref, new = runs.values()
    diff = float(np.nanmax(np.abs(new - ref)) / np.nanmax(np.abs(ref)))
    print(f"{len(shared)} candidates, {centres} centres, {inputs} inputs, 2 segments x {args.steps} steps")
    for name, seconds in best.items():
        print(f"  {name:36s} {seconds:7.2f} s CPU")
    a, b = best.values()
    print(f"  ratio reference / now: {a / b:.2f}x; largest relative difference of the outputs {diff:.1e}")


if __name__ == "__main__":
    main()
