"""FALKON and MoE training on CUDA against CPU, in one process, on the same data and seeds.

    python benchmarks/cuda_vs_cpu.py                      # FALKON n=1,000,000 and MoE on turboshaft-wf's rows
    python benchmarks/cuda_vs_cpu.py --falkon-n 100000 --moe-rows 20000 --moe-epochs 2 --size small

FALKON: the seeded synthetic problem of ``falkon_scale.py`` (smooth nonlinear regression,
noise sd 0.1, 10,000 test rows), fitted and predicted once per device with the same centres
(same seed); printed: fit and predict wall time, CG iterations, test MAE, and the largest
difference between the two devices' test predictions.

MoE: turboshaft-wf's training rows (``--moe-rows`` whole trajectories drawn as the runner
draws them) with that experiment's MoE options (input derivatives, standard-day correction,
simulation-error term), trained ``--moe-epochs`` epochs per device from the same seed:
once on CPU with one thread (what each worker of ``enginebench run -j N`` uses), once on CPU
with every core, once on CUDA. The TV derivatives are solved before the timed fits (each
fit then finds them in the in-process cache, as a grid's later fits do), and a one-epoch fit per
device runs first so first use (CUDA's start-up) is timed apart. Each fitted model then simulates the test
trajectories on CPU: the test RMAE shows whether the device changed the model, not only the speed.
The training step runs eagerly (``compile = false``) on every device unless ``--compile``.

Without CUDA the CUDA lines say so and the CPU lines still print. Quote the printed machine
line with every figure.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import torch

from enginebench.datasets import catalog
from enginebench.datasets.pools import make_samples
from enginebench.datasets.splits import make_splits
from enginebench.experiments.jobs import subsample_segments
from enginebench.experiments.spec import load_spec
from enginebench.methods.moe import MoE
from enginebench.methods.moe.preprocess import prepare
from enginebench.methods.numerics.falkon import FalkonSolver
from falkon_scale import N_TEST, NOISE_SD, make_problem


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def machine_line() -> str:
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no CUDA device"
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load average "
            f"{os.getloadavg()[0]:.1f}; torch {torch.__version__}; {gpu}")


def falkon(n: int, d: int, centres: int, seed: int, devices: list[str]) -> None:
    """Fit and predict the FALKON problem on each device; print times, MAE and the devices' difference."""
    X, y, X_test, y_test = make_problem(n, d, seed)
    gamma, lam = 1.0 / (4 * d), 1e-5 * n
    print(f"FALKON: n={n:,} d={d} centres={centres} gamma={gamma:.4g} lambda={lam:.4g}, float32 kernel blocks, "
          f"float64 CG (noise-floor MAE {NOISE_SD * np.sqrt(2 / np.pi):.4f}, training-mean MAE "
          f"{float(np.abs(y.mean() - y_test).mean()):.4f})")
    preds: dict[str, np.ndarray] = {}
    fit_s: dict[str, float] = {}
    for dev in devices:
        if dev.startswith("cuda"):  # CUDA's context and kernels load on first use: time that apart
            t0 = time.perf_counter()
            FalkonSolver(gamma, lam, centres=100, maxiter=2, device=dev).fit(X[:5000], y[:5000], np.random.default_rng(0))
            _sync(dev)
            print(f"  {dev:<6} start-up (first use, a 5,000-row fit) {time.perf_counter() - t0:8.2f} s")
        solver = FalkonSolver(gamma, lam, centres=centres, maxiter=30, tol=1e-5, device=dev, dtype=torch.float32)
        t0 = time.perf_counter()
        solver.fit(X, y, np.random.default_rng(seed + 1))
        _sync(dev)
        t_fit = fit_s[dev] = time.perf_counter() - t0
        t0 = time.perf_counter()
        preds[dev] = solver.predict(X_test)
        t_pred = time.perf_counter() - t0
        info = solver.info
        print(f"  {dev:<6} fit {t_fit:8.2f} s ({info['iterations']} CG iterations, residual {info['residual']:.1e}), "
              f"predict {N_TEST:,} rows {t_pred:6.3f} s, test MAE {float(np.abs(preds[dev] - y_test).mean()):.5f}, "
              f"threads {torch.get_num_threads()}")
    if len(preds) == 2:
        a, b = preds.values()
        print(f"  cpu / cuda fit time {fit_s['cpu'] / fit_s['cuda']:.1f}; largest |prediction difference| "
              f"{float(np.abs(a - b).max()):.2e} "
              f"(prediction scale {float(np.abs(a).max()):.2f})")


def moe(size: str, rows: int, epochs: int, seed: int, compile_step: bool, has_cuda: bool) -> None:
    """Train turboshaft-wf's MoE on each device from the same seed; print per-epoch times and test RMAE."""
    spec = load_spec("turboshaft-wf")
    ds = catalog.load("turboshaft", variant=size)
    split = make_splits(ds, kind="published")[0]
    train_all = make_samples(split.train, ["WF"], "simulation")
    test = make_samples(split.test, ["WF"], "simulation")
    sizes = np.array([len(s) for s in train_all.segments])
    train = train_all.take(subsample_segments(sizes, rows, np.random.default_rng(seed)))
    if compile_step:  # compile however short the fit (the method compiles only fits of COMPILE_MIN_STEPS steps)
        from enginebench.methods.moe import training

        training.COMPILE_MIN_STEPS = 0
    base = {**spec.method_options.get("moe", {}), "compile": compile_step}
    options = MoE(**base).options
    t0 = time.perf_counter()
    prepare(train, options)  # the TV derivatives, cached in-process for every fit below
    print(f"MoE (turboshaft-wf options, {'compiled' if compile_step else 'eager'} step): {len(train):,} training rows in "
          f"{len(train.segments)} trajectories, {epochs} epochs, batch {options['batch_size']}; "
          f"TV derivatives {time.perf_counter() - t0:.1f} s (once, before the timed fits)")
    hp = {"epochs": epochs, "n_experts": 3, "beta2": 1.0, "lr": 1e-3}
    cores = os.cpu_count() or 1
    runs = [("cpu", 1), ("cpu", cores)] + ([("cuda", None)] if has_cuda else [])
    view = test.without_targets()
    y = np.asarray(test.y)[:, 0]
    for dev in ["cpu"] + (["cuda"] if has_cuda else []):  # first use (CUDA context, kernels, caches) timed apart
        t0 = time.perf_counter()
        MoE(**base, device=dev).fit(train, {**hp, "epochs": 1}, np.random.default_rng(seed))
        _sync(dev)
        print(f"  {dev:<8} start-up and a 1-epoch fit {time.perf_counter() - t0:.1f} s")
    per_epoch: dict[str, float] = {}
    for dev, threads in runs:
        label = f"{dev} x{threads}" if threads else dev
        m = MoE(**base, device=dev, cpu_threads=threads)
        t0 = time.perf_counter()
        fitted = m.fit(train, hp, np.random.default_rng(seed))
        _sync(dev)
        wall = time.perf_counter() - t0
        per_epoch[label] = wall / epochs
        fitted.options["device"] = "cpu"  # simulate every model the same way: the test RMAE compares the models
        pred = np.concatenate([np.asarray(a).reshape(len(a), -1)[:, 0] for a in MoE(**base, device="cpu").predict(fitted, view)])
        rmae = 100 * float(np.mean(np.abs(pred - y)) / np.mean(np.abs(y)))
        print(f"  {label:<8} fit {wall:8.1f} s = {wall / epochs:.3f} s per epoch; final training loss "
              f"{fitted.loss_history[-1]:.5g}; test RMAE {rmae:.3f} %")
    if "cuda" in per_epoch:
        print(f"  per epoch: cpu x1 / cuda {per_epoch['cpu x1'] / per_epoch['cuda']:.1f}, "
              f"cpu x{cores} / cuda {per_epoch[f'cpu x{cores}'] / per_epoch['cuda']:.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--falkon-n", type=int, default=1_000_000, help="FALKON training rows (0 skips FALKON)")
    parser.add_argument("--d", type=int, default=40, help="FALKON features")
    parser.add_argument("--centres", type=int, default=2000, help="FALKON Nystroem centres")
    parser.add_argument("--size", choices=["small", "full"], default="full", help="turboshaft data size")
    parser.add_argument("--moe-rows", type=int, default=load_spec("turboshaft-wf").train_size,
                        help="MoE training rows (default: turboshaft-wf's train_size; 0 skips the MoE)")
    parser.add_argument("--moe-epochs", type=int, default=5, help="epochs per timed MoE fit")
    parser.add_argument("--compile", action="store_true", help="torch.compile the MoE training step on every device")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    has_cuda = torch.cuda.is_available()
    print(machine_line())
    if not has_cuda:
        print("CUDA: not available here; the CUDA lines are skipped")
    if args.falkon_n:
        falkon(args.falkon_n, args.d, args.centres, args.seed, ["cpu"] + (["cuda"] if has_cuda else []))
    if args.moe_rows:
        moe(args.size, args.moe_rows, args.moe_epochs, args.seed, args.compile, has_cuda)


if __name__ == "__main__":
    main()
