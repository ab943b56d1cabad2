"""Speed of the marine-diesel simulator and physical model, in one process.

Prints, for the data set of the chosen size, how many simulated seconds each runs per
wall-clock second (the reference is real time: the egt-hybrid paper reports its PM at 100-2500 x
real time) and samples per second:

* the generator (profile, true engine over every voyage row including logging gaps and
  lane warm-up, thermal blocks, sensors), timed end to end, rated on the logged rows;
* the PM over all rows at once (``pm.simulate_frame``) and segment by segment through
  the ``PhysicalModel`` protocol (``MarineDieselPM.simulate``), with the parameters
  calibrated on the egt-hybrid paper's FAT (calibration not timed).

Usage: python benchmarks/marine_speed.py [--size small|full] [--seed N]
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from enginebench.datasets.marine_diesel.calibration import seed_fat_params
from enginebench.datasets.marine_diesel.generate import SIZES, generate
from enginebench.datasets.marine_diesel.physical_model import MarineDieselPM
from enginebench.datasets.marine_diesel.pm import RACK, SPEED, simulate_frame


def _line(label: str, simulated_s: float, samples: int, wall_s: float) -> str:
    return (f"{label:<38} {wall_s:9.2f} s wall  {simulated_s / wall_s:14,.0f} x real time  "
            f"{samples / wall_s:14,.0f} samples/s")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=sorted(SIZES), default="full")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    params = seed_fat_params()                      # FAT calibration, not timed
    t0 = time.perf_counter()
    ds = generate(args.size, seed=args.seed)
    t_gen = time.perf_counter() - t0
    n = len(ds)
    simulated = n * ds.dt
    print(f"marine-diesel size={args.size} seed={args.seed}: {n:,} samples, {len(ds.segment_ids)} segments, "
          f"{simulated / 3600:,.0f} h logged at dt={ds.dt} s; {platform.processor() or platform.machine()}, "
          f"numpy {np.__version__}")
    print(_line("generator (true engine, end to end)", simulated, n, t_gen))

    t0 = time.perf_counter()
    pred = simulate_frame(params, ds.frame, ds.dt)
    t_pm = time.perf_counter() - t0
    print(_line("PM, all segments in one pass", simulated, n, t_pm))

    pm = MarineDieselPM(params)
    t0 = time.perf_counter()
    for _, part in ds.segments():
        pm.simulate(params, {SPEED: part[SPEED].to_numpy(), RACK: part[RACK].to_numpy()}, ds.dt)
    t_seg = time.perf_counter() - t0
    print(_line("PM, per segment (PhysicalModel API)", simulated, n, t_seg))
    for name, values in pred.items():
        y = ds.frame[name].to_numpy()
        print(f"  PM (seed-FAT calibration) {name}: MAE {np.mean(np.abs(values - y)):.1f} degC, "
              f"PPMCC {np.corrcoef(values, y)[0, 1]:.3f}")


if __name__ == "__main__":
    main()
