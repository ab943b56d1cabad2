"""The identification benchmarks' protocols, method by method, with the field's libraries in the same process.

Runs the built-in experiments ``silverbox`` and ``f16-gvt`` (or their ``-quick``
variants) exactly as ``enginebench run`` does for repetition 0: the experiment's records
split, its ``init_samples`` window, its selection (k-fold blocks inside the training
records, free-run RMSE), the selected point refit on all training rows, then a free run
of every test record from its init window. Every method of the experiment is run, plus
the peers ``sysidentpy-narx`` and ``n4sid`` when ``enginebench[peers]`` is installed.

Prints per method and target: test RMSE (in the output's unit), NRMSE, fit %, the
number of diverged test records, selection and final-fit wall time, and the free-run
speed of the test prediction in simulated seconds per wall second (x real time; and per
second of the process's CPU time, which a machine shared with other jobs leaves honest). For
Silverbox the RMSE on the first 32,000 evaluated test samples is printed as well: the
part of the 'arrow' whose amplitude stays inside the estimation data's (the rest is
extrapolation, where kernel models revert to the mean).

The datasets are imported from ``--data`` (default ``../shared/data``) into a temporary
data home unless they are already imported (``enginebench datasets import ...``).

Usage: python benchmarks/identification.py [--quick] [--experiments silverbox f16-gvt]
       [--methods arx narx ...] [--no-peers] [--data DIR]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from enginebench import registry
from enginebench.datasets import catalog
from enginebench.errors import EngineBenchError
from enginebench.experiments.jobs import Job, final_fit_rng, method_rng, refit_samples, training_samples
from enginebench.experiments.runner import prepare
from enginebench.experiments.selection import select
from enginebench.experiments.spec import load_spec
from enginebench.methods.peers import N4SID, SysIdentPyNARX
from enginebench.results import metrics

FIRST = {"silverbox": 32000}
"""Extra RMSE over the first N evaluated test samples, per dataset."""
SOURCES = {"silverbox": "silverbox", "f16-gvt": "f16-gvt"}


def _ensure_dataset(name: str, data: Path, home: Path) -> None:
    """Import the built-in ``name`` from ``data`` into ``home`` unless the current data home has it."""
    try:
        catalog.locate(name)
        return
    except EngineBenchError:
        pass
    os.environ["ENGINEBENCH_DATA"] = str(home)
    try:
        catalog.locate(name)
    except EngineBenchError:
        catalog.import_builtin(name, data / SOURCES[name])


def _methods(spec_methods: tuple[str, ...], chosen: list[str] | None, peers: bool) -> list[str]:
    names = list(chosen) if chosen else list(spec_methods)
    if peers and not chosen:
        names += [cls.name for cls in (SysIdentPyNARX, N4SID) if cls.available() is None and cls.name not in names]
    return names


def run_experiment(name: str, methods: list[str] | None, peers: bool) -> list[dict]:
    spec = load_spec(name)
    ctx = prepare(spec)
    rows = []
    first = FIRST.get(spec.dataset)
    for (target, window, split), problem in ctx.problems.items():
        train = training_samples(spec, problem, 0, split)
        test = problem.parts["test"]
        test = test.materialize() if hasattr(test, "materialize") else test
        view = test.without_targets()
        steps = sum(len(s.t) - spec.init_samples for s in test.segments)
        simulated_s = steps * test.dt
        y = test.y[:, 0]  # one target per problem
        sd = float(y.std())
        for mname in _methods(spec.methods, methods, peers):
            method = registry.get(mname)(**spec.method_options.get(mname, {}))
            rng = method_rng(spec, Job(target, window, split, mname, 0))
            row = {"experiment": name, "target": target, "method": mname, "unit": test.units.get(target, "")}
            try:
                t0 = time.perf_counter()
                params, record = select(method, train, spec.selection, rng, init_samples=spec.init_samples)
                t1 = time.perf_counter()
                fitted = method.fit(refit_samples(spec, problem, train, 0, split), params,
                                    final_fit_rng(spec, Job(target, window, split, mname, 0)))
                t2, c2 = time.perf_counter(), time.process_time()
                pred = method.predict(fitted, view)
                t3, c3 = time.perf_counter(), time.process_time()
            except EngineBenchError as exc:
                row["error"] = str(exc)
                rows.append(row)
                print(f"  {target:<14} {mname:<16} failed: {exc}", flush=True)
                continue
            yhat = np.concatenate(list(pred))[:, 0]
            row.update(
                rmse=metrics.rmse(y, yhat), nrmse=metrics.nrmse(y, yhat), fit=metrics.fit(y, yhat),
                diverged=int(np.sum(getattr(pred, "diverged", np.zeros(0)))), records=len(test.segments),
                select_s=t1 - t0, fit_s=t2 - t1, predict_s=t3 - t2, speed=simulated_s / max(t3 - t2, 1e-12),
                speed_cpu=simulated_s / max(c3 - c2, 1e-12),
                params={k: (v.item() if hasattr(v, "item") else v) for k, v in params.items()},
                warnings=record.get("warnings", []), std=sd,
            )
            if first and len(test.segments) == 1 and len(y) > first:
                row["rmse_first"] = metrics.rmse(y[:first], yhat[:first])
            rows.append(row)
            print(_line(row, first), flush=True)
    return rows


def _line(row: dict, first: int | None) -> str:
    scale, unit = (1e3, "m" + row["unit"]) if row["unit"] == "V" else (1.0, row["unit"])
    extra = f"  first {first:,}: {row['rmse_first'] * scale:8.3f}" if "rmse_first" in row else ""
    params = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in row["params"].items())
    return (f"  {row['target']:<14} {row['method']:<16} rmse {row['rmse'] * scale:9.4g} {unit:<6}{extra}  "
            f"nrmse {row['nrmse']:7.4f}  fit {row['fit']:7.2f} %  diverged {row['diverged']}/{row['records']}  "
            f"select {row['select_s']:7.1f} s  fit {row['fit_s']:6.1f} s  free run {row['speed']:8,.0f} x real time "
            f"({row['speed_cpu']:,.0f} x on CPU time)"
            f"  [{params}]" + (f"  WARN {'; '.join(row['warnings'])}" if row["warnings"] else ""))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiments", nargs="+", default=["silverbox", "f16-gvt"])
    parser.add_argument("--quick", action="store_true", help="run the -quick variants of the experiments")
    parser.add_argument("--methods", nargs="+", default=None, help="only these methods (default: the experiment's "
                                                                     "and the installed peers)")
    parser.add_argument("--no-peers", action="store_true", help="leave out sysidentpy-narx and n4sid")
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "data")
    args = parser.parse_args(argv)
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, numpy {np.__version__}; "
          f"peers: sysidentpy {'yes' if SysIdentPyNARX.available() is None else 'no'}, "
          f"nfoursid {'yes' if N4SID.available() is None else 'no'}", flush=True)
    with tempfile.TemporaryDirectory(prefix="enginebench-identification-") as home:
        for name in args.experiments:
            exp = f"{name}-quick" if args.quick and not name.endswith("-quick") else name
            spec = load_spec(exp)
            _ensure_dataset(spec.dataset, args.data, Path(home))
            print(f"\n{exp}: dataset {spec.dataset}, targets {', '.join(spec.targets)}, split {spec.split}, "
                  f"init_samples {spec.init_samples}, selection {spec.selection.kind} ({spec.selection.folds} folds, "
                  f"{spec.selection.criterion})", flush=True)
            run_experiment(exp, args.methods, not args.no_peers)


if __name__ == "__main__":
    main()
