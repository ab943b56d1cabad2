"""Where the time of a full experiment goes: a per-stage breakdown from a sample of its jobs.

Runs ``prepare`` (reading, splitting, raw arrays) once, then a sample of the experiment's
jobs in this process under cProfile, each written to a throw-away run store as the runner
does, and prints for each method the seconds per job of each stage (select, fit, predict
parts, metrics, write) and of the work inside them, wherever it happens (window features,
kernel matrices, factorisations and solves, scoring, MoE training epochs, the MoE's and
SINDy's regularised (TV) derivatives, free-run simulation: inclusive cumulative times, so
they overlap the stage that called them), then the extrapolation to the whole plan.

The sample takes ``--per-method`` jobs of every method, spread over targets, windows and
repetitions, so the extrapolation weighs each method by its number of jobs. Timings are
wall seconds of one process on this machine: say the load they ran under when you quote
them (``os.getloadavg`` is printed). CPU seconds of the process are printed beside them: on
shared cores they are the steadier figure. The process runs with the BLAS threads a run's
worker gets (cores // workers, as ``experiments/executors.py`` sets them): left at the
core count, OpenBLAS's thread hand-offs on loaded cores made a tridiagonalisation ~10x
slower and inflated the LAPACK-heavy methods' share (issue 18: MTL-KRLS looked 8x KRLS).

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

from enginebench.experiments.engine import plan
from enginebench.experiments.executor_base import limit_threads
from enginebench.experiments.executors import default_workers
from enginebench.experiments.jobs import run_job
from enginebench.experiments.runner import prepare
from enginebench.experiments.spec import load_spec
from enginebench.results.store import RunStore

STAGES: list[tuple[int, str, tuple[tuple[str, str], ...]]] = [
    (1, "select (model selection)", (("experiments/selection.py", "select"),)),
    (2, "window features", (("datasets/pools.py", "_features"),)),
    (2, "kernel matrices", (("methods/numerics/kernels.py", "sq_distances"), ("methods/numerics/kernels.py", "gaussian"),
                                  ("methods/numerics/kernels.py", "gaussian_apply"))),
    (2, "factorisations / solves", (("methods/numerics/shifted.py", "shifted_solutions"), ("methods/numerics/kernels.py", "from_kernel"))),
    (2, "scoring", (("results/metrics.py", "grid_scores"),)),
    (2, "MoE training epochs", (("methods/moe/training.py", "_train"),)),
    (2, "regularised derivatives (TV)", (("methods/numerics/derivatives.py", "differentiate"),)),
    (2, "simulation (free run)", (("methods/moe/simulation.py", "simulate"), ("methods/numerics/integrate.py", "integrate"))),
    (1, "fit (chosen point)", (("methods/", "fit"),)),
    (1, "predict parts", (("experiments/jobs.py", "predict_part"),)),
    (1, "metrics", (("results/metrics.py", "compute_metrics"),)),
    (1, "write", (("results/run_folder.py", "write_job"),)),
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
    """``per_method`` jobs of each method, spread evenly over its (window, target, split) groups and repetitions.

    Job i of n takes the group and the repetition at the middle of the i-th of n equal slices
    (groups ordered by window, then target), so one job per method falls on a middle window
    and two on the second and fourth quarter: the windows' feature counts, which set the cost of
    the kernel methods, are sampled across their range, not only the first window.
    """
    by_method: dict[str, list] = defaultdict(list)
    for job in jobs:
        by_method[job.method].append(job)
    chosen = []
    for method_jobs in by_method.values():
        groups = sorted({(j.window, j.target, j.split) for j in method_jobs})
        reps = sorted({j.repetition for j in method_jobs})
        index = {(j.window, j.target, j.split, j.repetition): j for j in method_jobs}
        for i in range(min(per_method, len(method_jobs))):
            group = groups[int((i + 0.5) * len(groups) / per_method) % len(groups)]
            rep = reps[int((i + 0.5) * len(reps) / per_method) % len(reps)]
            chosen.append(index.get((*group, rep), method_jobs[i]))
    return chosen


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment")
    parser.add_argument("--per-method", type=int, default=2, help="jobs profiled per method")
    parser.add_argument("--repeats", type=int, default=None, help="override the experiment's repetitions")
    parser.add_argument("--workers", type=int, default=2, help="workers assumed for the wall-time estimate")
    parser.add_argument("--threads", type=int, default=None,
                        help="BLAS threads (default: cores // workers, what a run's worker gets)")
    args = parser.parse_args(argv)
    threads = args.threads or max(1, default_workers() // max(1, args.workers))
    limit_threads(threads)  # as a run's worker process does (BLAS, OpenMP and torch)

    spec = load_spec(args.experiment)
    if args.repeats:
        spec = spec.with_overrides(repetitions=args.repeats)
    print(f"{spec.name}: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"{threads} thread(s), load {os.getloadavg()[0]:.1f} at start")
    t0 = time.perf_counter()
    ctx = prepare(spec)
    prepare_s = time.perf_counter() - t0
    jobs = plan(ctx)
    sample = _sample(jobs, args.per_method)
    counts: dict[str, int] = defaultdict(int)
    for job in jobs:
        counts[job.method] += 1

    per_method_s: dict[str, list[float]] = defaultdict(list)
    per_method_cpu: dict[str, list[float]] = defaultdict(list)
    per_method_stage: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    with tempfile.TemporaryDirectory() as tmp:
        run = RunStore(tmp).create(spec.name, spec.to_dict(), spec.config_hash(), {}, len(sample))
        for k, job in enumerate(sample, 1):
            prof = cProfile.Profile()
            t0, c0 = time.perf_counter(), time.process_time()
            prof.enable()
            rows, meta = run_job(ctx, job)
            run.write_job(job.key, rows, meta)
            prof.disable()
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            per_method_s[job.method].append(wall)
            per_method_cpu[job.method].append(cpu)
            for label, sec in _stage_seconds(pstats.Stats(prof)).items():
                per_method_stage[job.method][label] += sec
            print(f"  [{k}/{len(sample)}] {job.key}: {wall:.1f} s wall, {cpu:.1f} s CPU ({meta['status']})",
                  flush=True)

    print(f"\nprepare (read + split + arrays): {prepare_s:.1f} s")
    total_jobs_s = total_cpu_s = 0.0
    for method, walls in per_method_s.items():
        mean = sum(walls) / len(walls)
        cpu = sum(per_method_cpu[method]) / len(walls)
        total_jobs_s += mean * counts[method]
        total_cpu_s += cpu * counts[method]
        print(f"\n{method}: {len(walls)} job(s) profiled, {mean:.1f} s wall ({cpu:.1f} s CPU) per job, "
              f"{counts[method]} jobs in the plan -> {mean * counts[method] / 60:.1f} min")
        for want, heading in ((1, "stages of a job"), (2, "work inside them (select, fit or predict)")):
            print(f"  {heading}:")
            for depth, label, _funcs in STAGES:
                sec = per_method_stage[method].get(label, 0.0) / len(walls)
                if depth == want and sec >= 0.005:
                    print(f"    {label:<30} {sec:9.2f} s  {100 * sec / mean:5.1f} %")
    print(f"\nwhole plan: {len(jobs)} jobs, estimated {total_jobs_s / 3600:.2f} h of job time "
          f"-> {(prepare_s + total_jobs_s / max(1, args.workers)) / 3600:.2f} h wall on {args.workers} worker(s) "
          f"({(prepare_s + total_cpu_s / max(1, args.workers)) / 3600:.2f} h from CPU time, i.e. on idle cores); "
          f"load {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
