"""Where the time of a full experiment goes: a per-stage breakdown from a sample of its jobs.

Runs ``prepare`` (reading, splitting, raw arrays) once, then a sample of the experiment's
jobs in this process under cProfile, each written to a throw-away run store as the runner
does, and prints for each method the seconds per job of each stage (select, fit, predict
parts, metrics, write) and of the work inside them, wherever it happens (window features,
kernel matrices, factorisations and solves, scoring, MoE training epochs, free-run
simulation: inclusive cumulative times, so they overlap the stage that called them), then
the extrapolation to the whole plan.

The sample takes ``--per-method`` jobs of every method, spread over targets, windows and
repetitions, so the extrapolation weighs each method by its number of jobs. Timings are
wall seconds of one process on this machine: say the load they ran under when you quote
them (``os.getloadavg`` is printed).

Usage: python benchmarks/profile_full.py EXPERIMENT [--per-method 2] [--repeats N] [--workers 2]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import platform
import pstats
import tempfile
import time
from collections import defaultdict

from enginebench.experiments.jobs import run_job
from enginebench.experiments.runner import plan, prepare
from enginebench.experiments.spec import load_spec
from enginebench.results.store import RunStore

STAGES: list[tuple[int, str, tuple[tuple[str, str], ...]]] = [
    (1, "select (model selection)", (("experiments/selection.py", "select"),)),
    (2, "window features", (("datasets/samples.py", "_features"),)),
    (2, "kernel matrices", (("methods/kernels.py", "sq_distances"), ("methods/kernels.py", "gaussian"))),
    (2, "factorisations / solves", (("methods/shifted.py", "shifted_solutions"), ("methods/kernels.py", "from_kernel"))),
    (2, "scoring", (("experiments/selection.py", "grid_scores"),)),
    (2, "MoE training epochs", (("methods/moe/training.py", "_train"),)),
    (2, "simulation (free run)", (("methods/moe/simulation.py", "simulate"), ("methods/numerics/integrate.py", "integrate"))),
    (1, "fit (chosen point)", (("methods/", "fit"),)),
    (1, "predict parts", (("experiments/jobs.py", "predict_part"),)),
    (1, "metrics", (("results/metrics.py", "compute_metrics"),)),
    (1, "write", (("results/store.py", "write_job"),)),
]
"""(depth, label, (path suffix, function name) ...): a stage's time is the sum of its functions' cumulative times."""


def _stage_seconds(stats: pstats.Stats) -> dict[str, float]:
    """Seconds per stage label from one profile (cumulative time of the stage's functions)."""
    out: dict[str, float] = defaultdict(float)
    for (path, _line, func), (_cc, _nc, _tt, ct, callers) in stats.stats.items():  # type: ignore[attr-defined]
        path = path.replace(os.sep, "/")
        for _depth, label, funcs in STAGES:
            for suffix, name in funcs:
                if func != name or suffix not in path:
                    continue
                if name == "fit" and any(f == "fit" and "methods/" in p for (p, _l, f) in callers):
                    continue  # a method's fit called by another fit (cascades, refits): counted once, at the top
                out[label] += ct
    return out


def _sample(jobs: list, per_method: int) -> list:
    """``per_method`` jobs of each method, spread evenly over that method's plan."""
    by_method: dict[str, list] = defaultdict(list)
    for job in jobs:
        by_method[job.method].append(job)
    chosen = []
    for method_jobs in by_method.values():
        step = max(1, len(method_jobs) // per_method)
        chosen.extend(method_jobs[::step][:per_method])
    return chosen


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment")
    parser.add_argument("--per-method", type=int, default=2, help="jobs profiled per method")
    parser.add_argument("--repeats", type=int, default=None, help="override the experiment's repetitions")
    parser.add_argument("--workers", type=int, default=2, help="workers assumed for the wall-time estimate")
    args = parser.parse_args(argv)

    spec = load_spec(args.experiment)
    if args.repeats:
        spec = spec.with_overrides(repetitions=args.repeats)
    print(f"{spec.name}: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f} at start")
    t0 = time.perf_counter()
    ctx = prepare(spec)
    prepare_s = time.perf_counter() - t0
    jobs = plan(ctx)
    sample = _sample(jobs, args.per_method)
    counts: dict[str, int] = defaultdict(int)
    for job in jobs:
        counts[job.method] += 1

    per_method_s: dict[str, list[float]] = defaultdict(list)
    per_method_stage: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    with tempfile.TemporaryDirectory() as tmp:
        run = RunStore(tmp).create(spec.name, spec.to_dict(), spec.config_hash(), {}, len(sample))
        for k, job in enumerate(sample, 1):
            prof = cProfile.Profile()
            t0 = time.perf_counter()
            prof.enable()
            rows, meta = run_job(ctx, job)
            run.write_job(job.key, rows, meta)
            prof.disable()
            wall = time.perf_counter() - t0
            per_method_s[job.method].append(wall)
            for label, sec in _stage_seconds(pstats.Stats(prof)).items():
                per_method_stage[job.method][label] += sec
            print(f"  [{k}/{len(sample)}] {job.key}: {wall:.1f} s ({meta['status']})", flush=True)

    print(f"\nprepare (read + split + arrays): {prepare_s:.1f} s")
    total_jobs_s = 0.0
    for method, walls in per_method_s.items():
        mean = sum(walls) / len(walls)
        total_jobs_s += mean * counts[method]
        print(f"\n{method}: {len(walls)} job(s) profiled, {mean:.1f} s per job, {counts[method]} jobs in the plan "
              f"-> {mean * counts[method] / 60:.1f} min")
        for want, heading in ((1, "stages of a job"), (2, "work inside them (select, fit or predict)")):
            print(f"  {heading}:")
            for depth, label, _funcs in STAGES:
                sec = per_method_stage[method].get(label, 0.0) / len(walls)
                if depth == want and sec >= 0.005:
                    print(f"    {label:<30} {sec:9.2f} s  {100 * sec / mean:5.1f} %")
    print(f"\nwhole plan: {len(jobs)} jobs, estimated {total_jobs_s / 3600:.2f} h of job time "
          f"-> {(prepare_s + total_jobs_s / max(1, args.workers)) / 3600:.2f} h wall on {args.workers} worker(s); "
          f"load {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
