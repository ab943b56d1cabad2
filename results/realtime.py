"""The real-time figures of a run's jobs (``experiments/keep.py`` measures them) as one row per method.

Each simulation job's metric rows carry ``rt_median_us``, ``rt_p99_us``, ``rt_worst_us`` and ``rt_factor``
(the time of one model step over the test part and the sample period over the worst step); here they are
gathered per method: the median of the jobs' medians, the largest p99 and worst step, and the real-time
factor of that worst step. Figures are measured on the machine that ran the jobs, never asserted.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

RT_METRICS = ("rt_median_us", "rt_p99_us", "rt_worst_us", "rt_factor")
"""The real-time metric rows of a simulation job; ``table --metrics rt`` stands for all four."""


def step_figures(times: np.ndarray, dt: float, source: str) -> dict[str, Any]:
    """Median, p99 and worst step (microseconds) and the real-time factor dt / worst of ``times`` (seconds)."""
    times = np.asarray(times, dtype=np.float64)
    worst = float(times.max()) if times.size else float("nan")
    return {"source": source, "steps": int(times.size), "dt_s": float(dt),
            "median_us": float(np.median(times) * 1e6) if times.size else float("nan"),
            "p99_us": float(np.percentile(times, 99) * 1e6) if times.size else float("nan"),
            "worst_us": worst * 1e6, "rt_factor": float(dt / worst) if worst > 0 else float("inf")}


def expand_rt(metrics: list[str] | None) -> list[str] | None:
    """A metric list with ``rt`` replaced by the four real-time metrics."""
    if not metrics:
        return metrics
    out: list[str] = []
    for m in metrics:
        out += list(RT_METRICS) if m == "rt" else [m]
    return out


def realtime_frame(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per method: jobs, median step, p99 step and worst step (us) and dt / worst (empty without figures)."""
    rows = metrics[(metrics["status"] == "ok") & metrics["metric"].isin(RT_METRICS)]
    if rows.empty:
        return pd.DataFrame(columns=["method", "jobs", "median_us", "p99_us", "worst_us", "rt_factor"])
    keys = [c for c in ("method", "target", "window", "split", "repetition") if c in rows.columns]
    wide = rows.pivot_table(index=keys, columns="metric", values="value", aggfunc="first").reset_index()
    out = []
    for method, g in wide.groupby("method", sort=False):
        worst = float(g["rt_worst_us"].max())
        factor = float((g["rt_factor"] * g["rt_worst_us"]).max() / worst) if worst > 0 else float("inf")
        out.append({"method": method, "jobs": int(len(g.drop_duplicates(subset=[k for k in keys if k != "target"]))),
                    "median_us": float(g["rt_median_us"].median()), "p99_us": float(g["rt_p99_us"].max()),
                    "worst_us": worst, "rt_factor": factor})
    return pd.DataFrame(out)
