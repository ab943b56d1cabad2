"""Simulation speed of SINDy and MoE on the turboshaft test trajectories, and MoE training time, in one process.

The reference is real time: a trajectory recorded at 12 Hz for T seconds is simulated
in W wall seconds at T / W times real time (turboshaft-moe: both run faster than real time on
a laptop; the project's target is at least 1000 x on 2 cores). Each model is fitted
once on training trajectories of the published split (not timed for SINDy), then every
test trajectory is simulated open loop from its measured initial output in one batched
call (timed, best of ``--repeats``). The MoE training time is timed separately on the
training rows with the default hyperparameters (or ``--epochs``). The MoE runs with the
options of the experiment turboshaft-wf (``--moe-options experiment``, for target WF: input
derivatives, standard-day correction, output-error start, simulation-error term) or the
method's defaults (``--moe-options default``, the turboshaft-moe paper's derivative-only training).

``--breakdown`` instead profiles one MoE fit on ``--train-rows`` training rows (turboshaft-wf's
200,000 by default, the experiment's options, the first grid point) part by part, in one process:
preprocessing (TV derivatives solved, then found in the in-process cache as the grid's later
fits find them), warm start, and per epoch the derivative loss (forward + backward), the
simulation term (windows cut, rollout through ``affine_prefix_scan``, forward + backward) and the
Adam step, for the former per-step loop (``reference``) and the fused one (``fused``); then whole
epochs of the fused loop with the step compiled (``compiled``, the first epoch's compile timed
apart) and per fit: preprocessing + warm start + ``--epochs`` epochs, measured on ``--breakdown-epochs``
epochs and scaled. Quote the load (printed) with every figure: the machine is shared.

Usage: python benchmarks/turboshaft_speed.py [--size full|small] [--target WF|TRQ] [--threads N]
       [--fit-rows N] [--train-rows N] [--epochs N] [--device cpu|cuda] [--moe-options experiment|default]
       [--breakdown [--breakdown-epochs N]]
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
from enginebench.methods.moe import HYPERPARAMETERS, MoE
from enginebench.methods.sindy import SINDy


def _load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def breakdown(train, opts: dict, epochs: int, timed_epochs: int, seed: int) -> None:
    """Print where one MoE fit's time goes, part by part, for the reference, fused and compiled paths."""
    import copy

    from enginebench.methods.moe import training as tr
    from enginebench.methods.moe.fitted import torch_dtype
    from enginebench.methods.moe.model import MixtureOfExperts, moe_loss
    from enginebench.methods.moe.options import resolve_params
    from enginebench.methods.moe.preprocess import margin_matrix, prepare
    from enginebench.methods.moe.warmstart import lstsq_coefficients, warm_start
    from enginebench.methods.numerics.derivatives import clear_cache

    o = MoE(**opts).options
    hp = resolve_params({"epochs": epochs})
    dtype, dev = torch_dtype(o["dtype"]), torch.device("cpu")
    print(f"MoE fit breakdown: {len(train):,} training rows, {len(train.segments)} trajectories, "
          f"{hp['n_experts']} experts, batch {o['batch_size']}, sim_weight {o['sim_weight']}; {_load()}")
    clear_cache()
    t0 = time.perf_counter()
    p = prepare(train, o)
    t_cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    p = prepare(train, o)
    t_warm = time.perf_counter() - t0
    print(f"  preprocessing (TV derivatives solved)            {t_cold:9.2f} s")
    print(f"  preprocessing (TV derivatives from the cache)    {t_warm:9.2f} s   (every later fit on the same rows)")
    t0 = time.perf_counter()
    gen = torch.Generator().manual_seed(seed)
    margin = margin_matrix(o["max_time_constant"], p.sign, p.stats["d_scale"], train.target_names)
    net0 = MixtureOfExperts(p.V.shape[1], len(train.target_names), p.X.shape[1], hp["n_experts"], o["expert_hidden"],
                            hp["gate_hidden"], torch.as_tensor(p.sign), hp["k"], gen, dtype, torch.as_tensor(margin))
    warm_start(net0, lstsq_coefficients(p.X, p.D, p.sign, margin), p.sign, hp["k"], margin)
    shoot = tr._Shooting(p.Us, p.Z, p.T, o["shooting_window"], p.si, p.ei, p.stats["d_scale"]) if o["sim_weight"] > 0 else None
    t_ws = time.perf_counter() - t0
    print(f"  warm start (least squares, network)              {t_ws:9.2f} s")
    Vt, Xt, Dt = (torch.as_tensor(a, dtype=dtype) for a in (p.V, p.X, p.D))
    n, bs = len(Vt), int(o["batch_size"])
    n_steps = -(-n // bs)
    per_epoch: dict[str, float] = {}
    for path in ("reference", "fused"):
        fused = path == "fused"
        net = copy.deepcopy(net0).train()
        opt = torch.optim.Adam(net.parameters(), lr=hp["lr"])
        parts = dict(shuffle=0.0, derivative=0.0, simulation=0.0, adam=0.0)
        g = torch.Generator().manual_seed(seed)
        t_all = time.perf_counter()
        for _ in range(timed_epochs):
            t0 = time.perf_counter()
            perm = torch.randperm(n, generator=g)
            if shoot is not None:
                Uw, Hw, Zw = (torch.as_tensor(a, dtype=dtype) for a in shoot.cut(g))
                wperm = torch.randperm(len(Zw), generator=g)
                per = -(-len(Zw) // n_steps)
                if fused:
                    Uw, Hw, Zw = Uw[wperm], Hw[wperm], Zw[wperm]
            if fused:
                Vp, Xp, Dp = Vt[perm], Xt[perm], Dt[perm]
            parts["shuffle"] += time.perf_counter() - t0
            for step, a in enumerate(range(0, n, bs)):
                t0 = time.perf_counter()
                if fused:
                    v, x, d = Vp[a:a + bs], Xp[a:a + bs], Dp[a:a + bs]
                else:
                    idx = perm[a:a + bs]
                    v, x, d = Vt[idx], Xt[idx], Dt[idx]
                f, alpha = net(v, x)
                moe_loss(f, alpha, d, hp["beta1"], hp["beta2"], o["competitive"]).backward()
                t1 = time.perf_counter()
                parts["derivative"] += t1 - t0
                if shoot is not None and step * per < len(Zw):
                    lo, hi = step * per, min((step + 1) * per, len(Zw))
                    w = slice(lo, hi) if fused else wperm[lo:hi]
                    (o["sim_weight"] * shoot.loss(net, o, Uw[w], Hw[w], Zw[w], fused)).backward()
                t2 = time.perf_counter()
                parts["simulation"] += t2 - t1
                opt.step()
                opt.zero_grad(set_to_none=True)
                parts["adam"] += time.perf_counter() - t2
        per_epoch[path] = (time.perf_counter() - t_all) / timed_epochs
        print(f"  {path}: {per_epoch[path]:.3f} s per epoch ({n_steps} steps); per epoch: "
              + ", ".join(f"{k} {v / timed_epochs:.3f} s" for k, v in parts.items()) + f"; {_load()}")
    # the fused loop with the compiled step, through training's own _train
    saved = tr.COMPILE_MIN_STEPS
    tr.COMPILE_MIN_STEPS = 0
    try:
        walls = []
        for e in (1, timed_epochs + 1):  # the first call compiles (once per process and network shape)
            net = copy.deepcopy(net0)
            t0 = time.perf_counter()
            tr._train(net, p.V, p.X, p.D, {**hp, "epochs": e}, o, torch.Generator().manual_seed(seed), dev, dtype,
                      shoot, fused=True, compile=True)
            walls.append(time.perf_counter() - t0)
    finally:
        tr.COMPILE_MIN_STEPS = saved
    per_epoch["compiled"] = walls[1] / (timed_epochs + 1)
    compile_s = max(walls[0] - per_epoch["compiled"], 0.0)
    compiled_ok = tr.compiled_step_loss() is not None
    print(f"  compiled: {per_epoch['compiled']:.3f} s per epoch; compile {compile_s:.1f} s (first fit of a process "
          f"and network shape){'' if compiled_ok else ' -- torch.compile unavailable: eager'}; {_load()}")
    print(f"  per fit of {epochs} epochs (measured parts, epochs scaled from {timed_epochs}):")
    base = dict(reference=t_cold + t_ws, fused=t_warm + t_ws, compiled=t_warm + t_ws + compile_s)
    for path, first in base.items():
        total = first + epochs * per_epoch[path]
        print(f"    {path:<10} {total:8.1f} s  ({total / 60:.1f} min)")
    print("  (reference pays the TV derivatives every fit; fused and compiled the cached ones, as the grid's "
          "later fits do; compiled pays its compile once per process and number of experts)")


def _best_of(fn, repeats: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=["small", "full"], default="full", help="full = the turboshaft-moe paper's 13 h (default)")
    parser.add_argument("--target", default="WF")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)), help="CPU threads for torch/BLAS")
    parser.add_argument("--fit-rows", type=int, default=30000, help="training rows (whole trajectories) for the simulated models")
    parser.add_argument("--train-rows", type=int, default=load_spec("turboshaft-wf").train_size,
                        help="rows for the MoE training-time measurement (default: turboshaft-wf's train_size; 0 = all training rows)")
    parser.add_argument("--epochs", type=int, default=int(HYPERPARAMETERS["epochs"]))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--moe-options", choices=["experiment", "default"], default="experiment",
                        help="MoE options of the experiment turboshaft-wf (target WF only) or the method's defaults")
    parser.add_argument("--breakdown", action="store_true", help="profile one MoE fit part by part, then stop")
    parser.add_argument("--breakdown-epochs", type=int, default=2, help="epochs timed per path in --breakdown")
    args = parser.parse_args(argv)

    torch.set_num_threads(args.threads)
    from threadpoolctl import threadpool_limits

    threadpool_limits(args.threads)
    ds = catalog.load("turboshaft", variant=args.size)
    split = make_splits(ds, kind="published")[0]
    train_all = make_samples(split.train, [args.target], "simulation")
    test = make_samples(split.test, [args.target], "simulation")
    rng = np.random.default_rng(args.seed)
    sizes = np.array([len(s) for s in train_all.segments])
    if args.breakdown:
        opts = {"device": args.device, "cpu_threads": args.threads}
        if args.moe_options == "experiment" and args.target == "WF":
            opts = {**load_spec("turboshaft-wf").method_options.get("moe", {}), **opts}
        rows = subsample_segments(sizes, args.train_rows, rng) if args.train_rows else np.arange(len(train_all))
        breakdown(train_all.take(rows), opts, args.epochs, args.breakdown_epochs, args.seed)
        return
    train = train_all.take(subsample_segments(sizes, args.fit_rows, rng))
    simulated_s = float(sum((len(s) - 1) * test.dt for s in test.segments))
    samples = len(test)
    print(f"turboshaft size={args.size}, target {args.target}: {len(ds):,} samples; test part {len(test.segments)} "
          f"trajectories, {samples:,} samples, {simulated_s / 3600:.2f} h simulated at {1 / test.dt:g} Hz; "
          f"{platform.processor() or platform.machine()}, {args.threads} thread(s), torch {torch.__version__}, "
          f"device {args.device}")

    def line(label: str, wall: float, extra: str = "") -> None:
        print(f"{label:<44} {wall:9.3f} s wall {simulated_s / wall:14,.0f} x real time {samples / wall:14,.0f} samples/s"
              + (f"  {extra}" if extra else ""))

    prediction_view = test.without_targets()
    sindy = SINDy(derivative="kalman", derivative_chunk=512, threshold_scale="absolute")  # the turboshaft-moe paper's absolute threshold
    for degree in (1, 2, 3):  # the lowest threshold of the paper's range keeps most library terms
        fit = sindy.fit(train, {"degree": degree, "threshold": 0.01, "alpha": 1e-4}, rng)
        wall, preds = _best_of(lambda: sindy.predict(fit, prediction_view), args.repeats)
        label = f"SINDy degree {degree} ({int(np.count_nonzero(fit.coef))} terms), RK4"
        line(label, wall, f"diverged {int(preds.diverged.sum())}/{len(preds)} (stopped where they diverged)")
        if preds.diverged.any() and not preds.diverged.all():
            # a diverged trajectory stops early, which flatters the speed: time the others alone
            keep = np.flatnonzero(~preds.diverged)
            rows = np.concatenate([np.arange(sum(len(s) for s in test.segments[:k]), sum(len(s) for s in test.segments[:k + 1]))
                                   for k in keep])
            part = test.take(rows)
            sub_s = float(sum((len(s) - 1) * test.dt for s in part.segments))
            sub_wall, _ = _best_of(lambda: sindy.predict(fit, part.without_targets()), args.repeats)
            print(f"{'  ... non-diverged trajectories only':<44} {sub_wall:9.3f} s wall {sub_s / sub_wall:14,.0f} x real time "
                  f"{len(part) / sub_wall:14,.0f} samples/s  ({len(keep)} trajectories, {sub_s / 3600:.2f} h)")

    opts = {"device": args.device, "cpu_threads": args.threads}
    if args.moe_options == "experiment" and args.target == "WF":
        opts = {**load_spec("turboshaft-wf").method_options.get("moe", {}), **opts}
    print(f"MoE options: {', '.join(f'{k}={v}' for k, v in opts.items())}")
    moe = MoE(**opts)
    hp = {"epochs": args.epochs}
    fitted = moe.fit(train, hp, rng)
    for integrator in ("rk4", "euler"):
        m = MoE(**opts, integrator=integrator)
        fitted.options["integrator"] = integrator
        wall, preds = _best_of(lambda: m.predict(fitted, prediction_view), args.repeats)
        line(f"MoE {fitted.params['n_experts']} experts, {integrator}", wall, f"diverged {int(preds.diverged.sum())}/{len(preds)}")

    big = train_all.take(subsample_segments(sizes, args.train_rows, rng))
    t0 = time.perf_counter()
    MoE(**opts).fit(big, hp, rng)
    t_fit = time.perf_counter() - t0
    print(f"MoE training ({HYPERPARAMETERS['n_experts']} experts, {args.epochs} epochs, batch {moe.options['batch_size']}) on "
          f"{len(big):,} rows ({len(big.segments)} trajectories, incl. TV derivatives): {t_fit:.1f} s wall, "
          f"{t_fit / args.epochs:.2f} s per epoch")


if __name__ == "__main__":
    main()
