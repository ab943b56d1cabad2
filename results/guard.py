"""The guard: check a run against a published baseline (docs/reports.md).

The baseline file (its format, and making, writing, finding and reading one) is
``results/baseline.py``. This module is the
comparison: tolerances, the guard rule per entry, the verdict and its report.

Guard rule, per published entry: the bound is ``ci_high`` for a lower-is-better metric
(``ci_low`` for higher-is-better; the published mean where there is no interval); the
allowed limit is the bound plus the tolerance (minus, for higher-is-better). The
tolerance is absolute (``0.05``: metric units) or relative (``5%``: of the published
mean's magnitude). An entry is ``regressed`` when the run's mean is beyond the limit by
more than its reproduction noise, ``rtol`` times max(|limit|, |run mean|) (at least
``ROUNDING_RTOL``: the same computation on another BLAS build or CPU differs in the last
digits, and a deterministic method's interval is a point); ``missing`` when the run has
no value for it; ``more failures`` when the run has more failed repetitions than
published; otherwise ``ok``. Values of the run that the baseline does not list are
ignored. A different experiment, config hash or dataset hash, an unfinished run, or a
baseline that states no measured tolerance gives a warning (a failure with ``strict``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from enginebench.errors import DataError
from enginebench.results import reproduce
from enginebench.results.baseline import recorded_dataset_hash
from enginebench.results.compare import JOIN, num, text_table
from enginebench.results.summary import summarize

__all__ = [
    "GuardResult", "Tolerance", "check", "guard_run", "parse_tolerance", "report", "rtol_note"
]
"""The guard's names (the baseline file's are ``results/baseline.py``'s)."""


@dataclass(frozen=True)
class Tolerance:
    """Slack added to the published bound: absolute (metric units) or relative to |published mean|."""

    value: float = 0.0
    relative: bool = False

    def allowance(self, published_mean: np.ndarray) -> np.ndarray:
        mean = np.asarray(published_mean, dtype=float)
        return self.value * np.abs(mean) if self.relative else np.full(mean.shape, self.value)

    def __str__(self) -> str:
        return f"{self.value * 100:g}% of the published mean" if self.relative else f"{self.value:g} (absolute)"


def parse_tolerance(text: str | float | None) -> Tolerance:
    """``0.05`` -> absolute 0.05; ``5%`` -> 5 % of the published mean; empty/None -> 0."""
    if text is None or str(text).strip() == "":
        return Tolerance()
    raw = str(text).strip()
    m = re.fullmatch(r"([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(%?)", raw)
    if not m:
        raise DataError(f"--tolerance {raw!r} is not a number: give an absolute value (0.05) or a percentage of the published mean (5%)")
    value = float(m.group(1))
    if not math.isfinite(value):
        raise DataError(f"--tolerance {raw!r} is beyond the double range: give a finite tolerance (e.g. 5%)")
    return Tolerance(value / 100.0, True) if m.group(2) else Tolerance(value, False)


STATUS_ORDER = ("regressed", "more failures", "missing", "ok")
ROUNDING_RTOL = reproduce.ROUNDING_RTOL
"""Excess up to this fraction of max(|limit|, |run mean|) is floating-point rounding, not a regression
(an entry's measured ``rtol`` raises it)."""


@dataclass
class GuardResult:
    """Every published entry with the run's value, limit, excess and status; warnings about the match."""

    rows: pd.DataFrame
    tolerance: Tolerance
    warnings: list[str] = field(default_factory=list)
    strict: bool = False
    ignored: int = 0
    rtol: str = ""
    """The baseline's measured reproduction tolerance per method, as text ('' when it states none)."""

    @property
    def failures(self) -> pd.DataFrame:
        return self.rows[self.rows["status"] != "ok"]

    @property
    def passed(self) -> bool:
        return self.failures.empty and not (self.strict and self.warnings)


def check(baseline: dict[str, Any], summary: pd.DataFrame, tolerance: Tolerance = Tolerance()) -> tuple[pd.DataFrame, int]:
    """(rows, ignored): apply the guard rule to every published entry against a run's summary.

    rows has the JOIN columns, lower_is_better, published mean/ci_low/ci_high/n_repeats/n_failed,
    run_mean, run_n_repeats, run_n_failed, limit, excess (> 0: beyond the limit by that much),
    excess_rel (excess / |published mean|) and status. ``ignored`` counts run values not published.
    """
    pub = pd.DataFrame(baseline["entries"])
    pub["window"] = pub["window"].astype(float)
    run = summary[JOIN + ["mean", "n_repeats", "n_failed"]].rename(
        columns={"mean": "run_mean", "n_repeats": "run_n_repeats", "n_failed": "run_n_failed"}).copy()
    run["window"] = run["window"].astype(float)
    m = pub.merge(run, on=JOIN, how="left", validate="one_to_one")
    ignored = len(run) - int(m["run_mean"].notna().sum())
    lower = m["lower_is_better"].to_numpy(dtype=bool)
    mean = m["mean"].to_numpy(dtype=float)
    bound = np.where(lower, m["ci_high"].fillna(m["mean"]), m["ci_low"].fillna(m["mean"]))
    allow = tolerance.allowance(mean)
    m["limit"] = np.where(lower, bound + allow, bound - allow)
    value = m["run_mean"].to_numpy(dtype=float)
    m["excess"] = np.where(lower, value - m["limit"], m["limit"] - value)
    with np.errstate(divide="ignore", invalid="ignore"):
        m["excess_rel"] = np.where(mean != 0, m["excess"] / np.abs(mean), np.nan)
    missing = m["run_mean"].isna().to_numpy()
    rtol = m["rtol"].fillna(ROUNDING_RTOL).to_numpy(dtype=float) if "rtol" in m else np.full(len(m), ROUNDING_RTOL)
    rounding = np.maximum(rtol, ROUNDING_RTOL) * np.maximum(np.abs(m["limit"].to_numpy(dtype=float)), np.abs(value))
    regressed = ~missing & (m["excess"].to_numpy(dtype=float) > rounding)
    failures = ~missing & (m["run_n_failed"].fillna(0).to_numpy() > m["n_failed"].to_numpy())
    m["status"] = np.select([missing, regressed, failures], ["missing", "regressed", "more failures"], "ok")
    return m, max(ignored, 0)


def guard_run(run, baseline: dict[str, Any], tolerance: Tolerance = Tolerance(), strict: bool = False,
              dataset_hash: str | None = None) -> GuardResult:
    """Check a stored run against a loaded baseline (see the module docstring for the rule).

    ``dataset_hash``: the run's dataset content hash (default: the one the run recorded).
    """
    info, cfg = run.info(), run.config()
    rows, ignored = check(baseline, summarize(run.metrics(), interval=baseline.get("interval", "t")), tolerance)
    warnings = []
    if cfg.get("name") != baseline["experiment"]:
        warnings.append(f"run {run.id} is experiment {cfg.get('name')!r}, the baseline is {baseline['experiment']!r}")
    if info.get("config_hash") != baseline["config_hash"]:
        warnings.append(f"run {run.id} has config hash {str(info.get('config_hash'))[:12]}, the baseline "
                        f"{baseline['config_hash'][:12]}: the experiment was changed (repetitions, seed, methods, options...)")
    published_hash = baseline.get("dataset_hash")
    run_hash = (dataset_hash or recorded_dataset_hash(run)) if published_hash else None
    if published_hash and run_hash and run_hash != published_hash:
        warnings.append(f"the dataset differs from the published one (content hash {run_hash[:12]} vs {published_hash[:12]})")
    if info.get("status") != "finished":
        warnings.append(f"run {run.id} is {info.get('status')} ({len(run.job_files())}/{info.get('n_jobs', '?')} jobs)")
    if "reproducibility" not in baseline:
        warnings.append("the baseline states no measured reproduction tolerance (published before they were measured): "
                        "last-digit differences of another machine may fail it; republish it with 'enginebench publish'")
    return GuardResult(rows, tolerance, warnings, strict, ignored, rtol_note(baseline))


def rtol_note(baseline: dict[str, Any]) -> str:
    """The baseline's measured tolerance per method, for the verdict line ('' when none was measured)."""
    measured = (baseline.get("reproducibility") or {}).get("rtol")
    if not isinstance(measured, dict) or not measured:
        return ""
    return ", ".join(f"{m} {float(v):.2g}" for m, v in sorted(measured.items()))


def _published(r) -> str:
    if not np.isfinite(r.ci_low) and not np.isfinite(r.ci_high):
        return f"{num(r.mean, 5)} (no interval)"
    return f"{num(r.mean, 5)} [{num(r.ci_low, 5)}, {num(r.ci_high, 5)}]"


def report(result: GuardResult, run_id: str = "", baseline_path: str = "", all_rows: bool = False) -> str:
    """What the guard found, as text: a verdict line, warnings, and a table of what failed (or of everything)."""
    rows = result.rows
    failed = result.failures
    where = f" {run_id}" if run_id else ""
    against = f" against {baseline_path}" if baseline_path else ""
    counts = ", ".join(f"{int((failed['status'] == s).sum())} {s}" for s in STATUS_ORDER[:-1] if (failed["status"] == s).any())
    lines = []
    if result.passed:
        lines.append(f"guard passed: run{where}{against}: all {len(rows)} published values are within their interval "
                     f"plus tolerance {result.tolerance}" + (f"; {result.ignored} value(s) of the run not published, ignored" if result.ignored else ""))
    elif failed.empty:
        lines.append(f"guard FAILED (strict): run{where}{against}: every value is within its limit, but the run does not match the baseline")
    else:
        lines.append(f"guard FAILED: run{where}{against}: {len(failed)} of {len(rows)} published values fail ({counts}); "
                     f"tolerance {result.tolerance}")
    if result.rtol:
        lines.append(f"reproduction tolerance (relative, measured when published, per method): {result.rtol}")
    lines += [f"warning: {w}" for w in result.warnings]
    shown = rows if all_rows else failed
    if shown.empty:
        from enginebench.results.term import note_text

        return note_text(lines)
    shown = shown.assign(_order=shown["status"].map(STATUS_ORDER.index)).sort_values(
        ["_order", "excess_rel"], ascending=[True, False], kind="stable")
    header = ["status", "target", "mode", "window", "split", "method", "metric", "better", "published mean [interval]",
              "run mean", "allowed limit", "excess", "excess %"]
    body = []
    for r in shown.itertuples():
        missing = not np.isfinite(r.run_mean)
        status = r.status + (f" ({int(r.run_n_failed)} vs {int(r.n_failed)} failed)" if r.status == "more failures" else "")
        body.append([status, r.target, r.mode, f"{r.window:g}", r.split, r.method, r.metric,
                     "lower" if r.lower_is_better else "higher", _published(r),
                     "missing" if missing else num(r.run_mean, 5), num(r.limit, 5),
                     "" if missing else f"{r.excess:+.3g}", "" if missing or not np.isfinite(r.excess_rel) else f"{r.excess_rel:+.1%}"])
    right = [False] * 8 + [True] * 5
    note = ("excess = how far the run's mean is beyond the allowed limit (published interval bound plus tolerance); "
            "positive = regressed")
    from enginebench.results.term import note_text

    return note_text(lines) + "\n" + text_table(header, body, right) + note_text([note])
