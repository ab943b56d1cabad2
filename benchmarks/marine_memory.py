"""Peak memory of a full-size marine-diesel run (issue 7, item 5): target under 8 GiB.

Runs the built-in ``marine-diesel-egt`` experiment on the full synthetic data set
(3347 h at 1/3 Hz, about 4.0 M rows x 45 channels) through the ``enginebench run``
command in a child process, and samples the resident memory of that process and all its
workers every 0.2 s (from /proc: Linux only). Printed: the peak of the whole process
tree's memory as proportional set size (PSS: the raw data, memory-mapped and shared by
the workers, counted once) and as summed resident size (RSS: shared pages counted in
every process), the peak of each process, the wall time, and, for scale, what the eager
feature matrices of one target and window would take.

Only the repetitions and grid sizes are reduced (``--repeats``, ``--grid``): memory does
not grow with either (one job at a time per worker, 1,000 training rows per job), so the
peak stands for the 30-repetition, 41-point run. Every target, window and method of the
full experiment runs.

Usage: python benchmarks/marine_memory.py [--size full] [--repeats 1] [--grid 3] [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from pathlib import Path

import tomli_w

from enginebench.datasets import catalog
from enginebench.datasets.io import read_metadata
from enginebench.experiments.spec import load_spec

PAGE = os.sysconf("SC_PAGE_SIZE")


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def _pss(pid: int) -> int:
    """Proportional set size: shared pages (the memory-mapped raw data) split among the processes mapping them."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) * 1024
    except (OSError, IndexError, ValueError):
        pass
    return 0


def _rss(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * PAGE
    except (OSError, IndexError, ValueError):
        return 0


class TreeSampler(threading.Thread):
    """Samples the summed RSS of a process and its descendants until stopped."""

    def __init__(self, pid: int, period: float = 0.2) -> None:
        super().__init__(daemon=True)
        self.pid, self.period = pid, period
        self.peak_total = 0
        self.peak_pss = 0
        self.peak_each: dict[int, int] = {}
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.is_set():
            pids, todo = [], [self.pid]
            while todo:
                p = todo.pop()
                pids.append(p)
                todo += _children(p)
            sizes = {p: _rss(p) for p in pids}
            self.peak_total = max(self.peak_total, sum(sizes.values()))
            self.peak_pss = max(self.peak_pss, sum(_pss(p) for p in pids))
            for p, v in sizes.items():
                self.peak_each[p] = max(self.peak_each.get(p, 0), v)
            self._halt.wait(self.period)

    def stop(self) -> None:
        self._halt.set()
        self.join()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=["small", "full"], default="full")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--grid", type=int, default=3, help="points per log-grid axis (41 in the experiment)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    args = parser.parse_args(argv)

    spec = load_spec("marine-diesel-egt")
    path = catalog.locate(spec.dataset, variant=args.size)   # generates the data set on first use (not measured)
    doc = read_metadata(path)
    config = tomllib.loads(tomli_w.dumps(spec.to_dict()))
    config.update(name=f"marine-diesel-egt-memory-{args.size}", dataset_variant=args.size, repetitions=args.repeats)
    for options in config["method_options"].values():
        for key in ("gamma_grid", "lambda_grid", "theta_grid"):
            if key in options:
                options[key] = [options[key][0], options[key][1], args.grid]
    n_in = sum(1 for c in doc["schema"].values() if c["role"] == "input")
    lags = int(max(spec.windows) / doc["dt"])
    eager_gib = doc["rows"] * (n_in * (lags + 1) + lags) * 8 / 2**30
    with tempfile.TemporaryDirectory() as tmp:
        exp = Path(tmp) / "experiment.toml"
        exp.write_text(tomli_w.dumps(config))
        env = {**os.environ, "ENGINEBENCH_STORE": str(Path(tmp) / "runs")}
        cmd = [sys.executable, "-c", "from enginebench.cli.main import main; main()", "run", str(exp), "--quiet", "--jobs", str(args.jobs)]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        sampler = TreeSampler(proc.pid)
        sampler.start()
        output, _ = proc.communicate()
        sampler.stop()
        wall = time.perf_counter() - t0
    if proc.returncode != 0:
        print(output)
        raise SystemExit(f"the run failed with exit code {proc.returncode}")
    print(output.rstrip())
    print()
    print(f"data set: marine-diesel {args.size}: {doc['rows']:,} rows, {len(doc['schema'])} channels ({n_in} inputs), "
          f"dt = {doc['dt']:g} s")
    print(f"run: {len(spec.targets)} targets x windows {spec.windows} x {len(spec.methods)} methods, "
          f"{args.repeats} repetition(s), {args.grid}-point grids, {args.jobs} workers, train_size {spec.train_size}")
    print(f"for scale: eager lagged features of every row at Delta = {max(spec.windows):g} s would take {eager_gib:.1f} GiB "
          "per target and window")
    print(f"peak memory of the whole process tree: {sampler.peak_pss / 2**30:.2f} GiB proportional (PSS, shared pages "
          f"counted once; target < 8 GiB), {sampler.peak_total / 2**30:.2f} GiB summed resident (RSS, shared pages "
          "counted in every process that maps them)")
    for pid, peak in sorted(sampler.peak_each.items(), key=lambda kv: -kv[1])[:4]:
        print(f"  pid {pid}: peak {peak / 2**30:.2f} GiB")
    print(f"wall time: {wall:.0f} s; load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
