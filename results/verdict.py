"""The verdict a report opens on: one line per (target, mode, window, test part) block.

Each line names the winner (the lowest mean of the primary metric: rmse in simulation
mode, mae otherwise, the metric of the paired tests), its margin over the best baseline
(the methods of family "baseline": the training mean ``tables.BASELINE``, the linear
baseline of ``tables.LINEAR_BASELINES``, the naive ones) with the paired test between
the two as ``tables.paired_tests`` computed it (raw and Holm-adjusted over the same
family the table lists), how many methods beat the training mean, and the block's
failed jobs and warnings. Where a baseline wins, the margin is the best other model's
distance above it. Nothing is recomputed here that the tables compute differently.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Mapping

import numpy as np
import pandas as pd

from enginebench.results.summary import BASELINE
from enginebench.results.tables import LINEAR_BASELINES, NAIVE_BASELINES

BASELINE_FAMILY = "baseline"
"""The family that marks a method as a baseline (``Method.family``), stored in every metric row."""


@dataclass(frozen=True)
class Verdict:
    """The headline of one block; ``text()`` is the sentence the report and ``table`` print."""

    target: str
    mode: str
    window: float
    split: str
    metric: str
    winner: str
    winner_mean: float
    winner_is_baseline: bool
    versus: str | None
    """The best baseline (or, where a baseline wins, the best other method); None when there is none."""
    versus_mean: float
    n_pairs: int
    t_pvalue: float
    t_pvalue_holm: float
    test_note: str
    """Why there is no paired test ("n = 1: no paired test", identical repetitions...); "" when there is one."""
    beat_mean: int | None
    """Methods whose mean is below the training mean's (None: the training mean did not run in this block)."""
    n_others: int
    """Methods of the block other than the training mean, with a finite mean."""
    failed_jobs: int
    warnings: int

    @property
    def where(self) -> str:
        """The block in words: the target, its window in window mode (Delta 0 s too: a run's windows are told
        apart), its part where it is not "test"."""
        parts = [self.target]
        if self.mode == "window":
            parts.append(f"Delta {self.window:g} s")
        if self.split != "test":
            parts.append(self.split)
        return ", ".join(parts)

    @property
    def margin(self) -> float:
        """How far the winner is below ``versus``, as a fraction of ``versus``'s mean (nan without one)."""
        if self.versus is None or not np.isfinite(self.versus_mean) or self.versus_mean == 0:
            return float("nan")
        return (self.versus_mean - self.winner_mean) / abs(self.versus_mean)

    def test_text(self) -> str:
        """``paired t p = 0.003, Holm 0.01`` or why there is no test."""
        if self.test_note:
            return self.test_note
        return f"paired t p = {self.t_pvalue:.2g}, Holm {self.t_pvalue_holm:.2g}"

    def text(self) -> str:
        """The verdict as one sentence."""
        head = f"{self.where}: {self.winner} best ({self.metric} {self.winner_mean:.4g})"
        if self.versus is None:
            head += "; only baselines ran" if self.winner_is_baseline else "; no baseline ran"
        elif self.winner_is_baseline:
            above = (self.versus_mean - self.winner_mean) / abs(self.winner_mean) if self.winner_mean else float("nan")
            head = (f"{self.where}: {self.winner} (a baseline) best ({self.metric} {self.winner_mean:.4g}); "
                    f"the best other method, {self.versus}, is {_percent(above)} % above it "
                    f"({self.test_text()})")
        else:
            head += f", {_percent(self.margin)} % below {self.versus} ({self.test_text()})"
        if self.beat_mean is None:
            mean = "no training mean in this block"
        else:
            mean = f"{self.beat_mean} of {self.n_others} method{'s' * (self.n_others != 1)} beat the training mean"
        return (f"{head}; {mean}; {self.failed_jobs} failed job{'s' * (self.failed_jobs != 1)}, "
                f"{self.warnings} warning{'s' * (self.warnings != 1)}")


def _percent(fraction: float) -> str:
    """A fraction as a percentage: whole numbers from 10 %, one decimal below."""
    if not np.isfinite(fraction):
        return "n/a"
    pct = 100.0 * fraction
    return f"{pct:.0f}" if abs(pct) >= 10 else f"{pct:.1f}"


def _baselines(raw: pd.DataFrame) -> set[str]:
    """The run's baseline methods: family "baseline" in the metric rows, else the tables' named baselines."""
    names: set[str] = set()
    if "family" in raw:
        names |= set(raw.loc[raw["family"] == BASELINE_FAMILY, "method"].astype(str))
    if not names:  # rows written before the family was stored
        names = {BASELINE, *LINEAR_BASELINES, *NAIVE_BASELINES}
    return names


def _is_test(split: str) -> bool:
    return split == "test" or split.startswith("test@")


def _job_counts(metas: Iterable[Mapping[str, Any]], targets: set[str]) -> dict[tuple[str, float], tuple[int, int]]:
    """(failed jobs, warnings) per (target, window) from the jobs' metadata; a job whose target is none of the
    table's (one fitting every target at once) counts for each of them."""
    out: dict[tuple[str, float], tuple[int, int]] = {}
    for meta in metas:
        target, window = str(meta.get("target", "")), float(meta.get("window", 0.0) or 0.0)
        failed = int(meta.get("status") not in (None, "ok"))
        warned = len(meta.get("warnings") or [])
        for t in ([target] if target in targets else sorted(targets)):
            f, w = out.get((t, window), (0, 0))
            out[(t, window)] = (f + failed, w + warned)
    return out


def _failed_from_rows(raw: pd.DataFrame) -> dict[tuple[str, float], int]:
    """Failed jobs per (target, window) from the metric rows alone (when no job metadata is given)."""
    bad = raw[raw["status"] != "ok"].drop_duplicates(["target", "window", "method", "repetition"])
    return {(str(t), float(w)): int(n) for (t, w), n in bad.groupby(["target", "window"]).size().items()}


def verdicts(raw: pd.DataFrame, summary: pd.DataFrame, paired: pd.DataFrame | None, metric: str,
             metas: Iterable[Mapping[str, Any]] | None = None) -> list[Verdict]:
    """One ``Verdict`` per (target, mode, window, test part) block of ``summary`` that has ``metric``.

    ``raw``: the run's metric rows (``Run.metrics()``), for the families and failed jobs;
    ``summary``: ``tables.summarize(raw)``; ``paired``: ``tables.paired_tests(raw, metric)``
    (None or empty: no test); ``metas``: the jobs' metadata (``Run.job_metas().values()``),
    for failed jobs and warnings (without it, failed jobs come from ``raw`` and warnings are 0).
    """
    rows = summary[(summary["metric"] == metric) & summary["split"].astype(str).map(_is_test)]
    if rows.empty:
        return []
    baselines = _baselines(raw)
    targets = set(rows["target"].astype(str))
    if metas is not None:
        counts = _job_counts(metas, targets)
    else:
        counts = {k: (n, 0) for k, n in _failed_from_rows(raw).items()}
    tests = paired if paired is not None else pd.DataFrame()
    out = []
    for (target, mode, window, split), block in rows.groupby(["target", "mode", "window", "split"], sort=False):
        block = block[np.isfinite(block["mean"].to_numpy(dtype=float))]
        if block.empty:
            continue
        means = dict(zip(block["method"].astype(str), block["mean"].astype(float)))
        n_rep = dict(zip(block["method"].astype(str), block["n_repeats"].astype(int)))
        winner = min(means, key=means.__getitem__)
        win_base = winner in baselines
        pool = [m for m in means if m != winner and ((m not in baselines) if win_base else (m in baselines))]
        versus = min(pool, key=means.__getitem__) if pool else None
        p, p_holm, n_pairs, note = float("nan"), float("nan"), 0, ""
        if versus is not None:
            found = _test_row(tests, target, mode, window, split, versus, winner)
            if found is not None:
                p, p_holm, n_pairs = float(found["t_pvalue"]), float(found["t_pvalue_holm"]), int(found["n_pairs"])
                note = str(found["note"]) if isinstance(found.get("note"), str) else ""
                if not note and not np.isfinite(p_holm):
                    p_holm = p  # a family of one test: Holm changes nothing
            elif min(n_rep[winner], n_rep[versus]) < 2:
                note = "n = 1: no paired test"
            else:
                note = "no paired test"
        base = means.get(BASELINE)
        others = [m for m in means if m != BASELINE]
        beat = None if base is None else sum(means[m] < base for m in others)
        failed, warned = counts.get((str(target), float(window)), (0, 0))
        out.append(Verdict(str(target), str(mode), float(window), str(split), metric, winner, means[winner], win_base,
                           versus, means.get(versus, float("nan")) if versus else float("nan"), n_pairs, p, p_holm,
                           note, beat, len(others), failed, warned))
    return out


def _test_row(tests: pd.DataFrame, target, mode, window, split, method: str, versus: str) -> pd.Series | None:
    """The paired test of ``method`` against ``versus`` in one block, as ``paired_tests`` listed it."""
    if tests.empty:
        return None
    hit = tests[(tests["target"] == target) & (tests["mode"] == mode) & (tests["window"] == window)
                & (tests["split"] == split) & (tests["method"] == method) & (tests["versus"] == versus)]
    return None if hit.empty else hit.iloc[0]


def verdict_lines(verdicts_: Iterable[Verdict]) -> list[str]:
    """Each verdict's sentence."""
    return [v.text() for v in verdicts_]
