"""The chosen model of each job of a run: its selected hyperparameters and the selection scores behind them.

``picks_frame(run)`` is one row per job with the values it used (read from each job file's
metadata, ``params`` and ``search``); ``folds_frame(run)`` is the per-resample (bootstrap
resample or fold) scores of each job's selected point and its runners-up, read from the
job's stored selection table. ``runs show`` prints ``picks_lines``, ``table --picks`` and
``table --folds`` print ``picks_text``/``folds_text``; Python reaches the same frames
through ``enginebench.api``.

A job has a selection table only when it scored a grid (two points or more, a selection
kind other than ``none``) in a run made since tables were stored; ``missing_folds_lines``
says which jobs have none and why.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import pandas as pd

from enginebench.results.run_folder import Run

COORDS = ["method", "target", "window", "split", "repetition"]
"""A job's coordinates, the first columns of both frames."""
PARAM = "param:"
"""Prefix of the hyperparameter columns (as in ``Run.selection_table``)."""
RESAMPLE = "resample:"
"""Prefix of ``folds_frame``'s per-resample score columns (``resample:0``, ``resample:1``...)."""
TERM_RESAMPLES = 10
"""Per-resample score columns a term table shows at most (csv gives all)."""


def _how(meta: dict[str, Any]) -> str:
    """How a job got its values: selected (a grid was scored), fixed (one point, or kind none), none, or failed."""
    params, search = meta.get("params"), meta.get("search") or {}
    if params is None:
        return "failed"
    if not params:
        return "none"
    return "selected" if "best_score" in search else "fixed"


def picks_frame(run: Run) -> pd.DataFrame:
    """One row per job: method, target, window, split, repetition, job (its key), status, how ('selected',
    'fixed': a one-point grid or selection kind 'none', 'none': nothing to select, 'failed': failed before
    choosing), grid_size, resamples, score (the selected point's mean selection score), folds_stored (whether
    its per-resample scores are stored) and one ``param:<name>`` column per hyperparameter (empty where a
    job's method lacks it). Rows sorted by the coordinates; damaged job files are left out."""
    rows = []
    for key, meta in run.job_metas().items():
        search = meta.get("search") or {}
        row: dict[str, Any] = {c: meta.get(c) for c in COORDS}
        row.update(job=key, status=meta.get("status", "ok"), how=_how(meta), grid_size=search.get("grid_size"),
                   resamples=search.get("resamples"), score=search.get("best_score"),
                   folds_stored=isinstance(meta.get("selection_file"), dict))
        row.update({PARAM + str(k): v for k, v in (meta.get("params") or {}).items()})
        rows.append(row)
    fixed = [*COORDS, "job", "status", "how", "grid_size", "resamples", "score", "folds_stored"]
    if not rows:
        return pd.DataFrame(columns=fixed)
    frame = pd.DataFrame(rows)
    params = [c for c in frame.columns if c.startswith(PARAM)]
    frame = frame[fixed + params].sort_values(COORDS, kind="stable", key=_sort_key).reset_index(drop=True)
    return frame.astype({"grid_size": "Int64", "resamples": "Int64", "score": "float64"})


def _sort_key(column: pd.Series) -> pd.Series:
    return column.astype(str) if column.dtype == object else column


def value_text(value: Any) -> str:
    """A hyperparameter value as printed: numbers with 6 significant digits (8, 0.01, 1e-10), others as text."""
    if isinstance(value, (bool, np.bool_)) or value is None:
        return str(value)
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    return str(value)


def _present(value: Any) -> bool:
    return not (value is None or isinstance(value, float) and np.isnan(value))


def _params(frame: pd.DataFrame) -> list[str]:
    return [c for c in frame.columns if c.startswith(PARAM) and frame[c].map(_present).any()]


def _group_label(frame: pd.DataFrame) -> list[str]:
    """The coordinates that name a group of repetitions: method and target, plus window and split when they vary."""
    varying = [c for c in ("window", "split") if frame[c].astype(str).nunique() > 1]
    return ["method", "target", *varying]


def _group_line(label: str, group: pd.DataFrame) -> str:
    n = len(group)
    chose = group[group["how"].isin(["selected", "fixed"])]
    failed = int((group["how"] == "failed").sum())
    tail = f"; {failed} failed before choosing" if failed else ""
    if chose.empty:
        what = "every job failed before choosing" if failed == n else "nothing to select"
        return f"{label}: {what} ({n} job{'s' if n > 1 else ''})"
    parts, agree = [], True
    for column in _params(chose):
        counts = Counter(value_text(v) for v in chose[column] if _present(v))
        total = sum(counts.values())
        ranked = sorted(counts.items(), key=lambda kv: -kv[1])
        name = column[len(PARAM):]
        if len(ranked) == 1 and total == len(chose):
            parts.append(f"{name}={ranked[0][0]}")
        else:
            agree = False
            parts.append(f"{name}=" + ", ".join(f"{v} ({k}/{total})" for v, k in ranked))
    fixed = " [fixed: nothing scored]" if (chose["how"] == "fixed").all() else ""
    if agree:
        return f"{label}: {' '.join(parts)}{fixed} ({'all ' if len(chose) > 1 else ''}{len(chose)} "\
               f"job{'s' if len(chose) > 1 else ''}{tail})"
    return f"{label}: {'; '.join(parts)}{fixed} ({len(chose)} jobs{tail})"


def picks_lines(picks: pd.DataFrame) -> list[str]:
    """One line per method x target (x window, split where the run has several) of ``picks_frame``: the values
    all its repetitions picked (``krls y: gamma=0.1 lambda=0.01 (all 3 jobs)``), or where they differ each value
    with how many jobs picked it (``gamma=0.1 (2/3), 1 (1/3)``)."""
    if picks.empty:
        return []
    keys = _group_label(picks)
    out = []
    for coords, group in picks.groupby(keys, sort=False, dropna=False):
        label = " ".join(value_text(c) if k != "window" else f"window {value_text(c)}" for k, c in zip(keys, coords))
        out.append(_group_line(label, group))
    return out


def _display(frame: pd.DataFrame, columns: list[str]) -> pd.DataFrame:
    """``columns`` of ``frame`` as text for a term table: values through ``value_text``, blanks where absent."""
    shown = frame[columns].copy()
    for c in columns:
        shown[c] = [value_text(v) if _present(v) else "" for v in frame[c]]
    return shown.rename(columns=lambda c: c[len(PARAM):] if c.startswith(PARAM) else c)


def _grid(shown: pd.DataFrame) -> str:
    """A ``_display`` frame as a terminal table (``results.term.grid``): words left, numbers right."""
    from enginebench.results.term import grid

    text = {"target", "split", "status", "job", "method"}
    return grid([str(c) for c in shown.columns], shown.itertuples(index=False, name=None),
                right=[c not in text for c in shown.columns])


_HOW = {"selected": "selected", "fixed": "fixed: nothing scored", "failed": "failed before choosing"}


def picks_text(picks: pd.DataFrame) -> str:
    """The term table of ``picks_frame``: one block per method (its own hyperparameter columns), one row per job;
    ``score`` is the selected point's mean selection score, ``grid`` the number of points searched."""
    if picks.empty:
        return "no finished job yet\n"
    blocks = []
    for method, group in picks.groupby("method", sort=False, dropna=False):
        n = f"{len(group)} job{'s' if len(group) > 1 else ''}"
        if (group["how"] == "none").all():
            blocks.append(f"{method}: nothing to select ({n})")
            continue
        columns = ["target", "window", "split", "repetition", *_params(group), "score", "grid_size"]
        if (group["status"] != "ok").any():
            columns.append("status")
        hows = ", ".join(_HOW.get(h, h) for h in dict.fromkeys(group["how"]))
        table = _grid(_display(group, columns).rename(columns={"grid_size": "grid"}))
        blocks.append(f"{method} ({n}; {hows}):\n{table.rstrip()}")
    return "\n\n".join(blocks) + "\n"


def folds_frame(run: Run, top: int = 3) -> pd.DataFrame:
    """The selection scores of each job that stored them: its ``top`` best grid points by mean score over the
    resamples or folds (the selected point always included), one row each: the job's coordinates, job, rank (1 =
    lowest mean), point, chosen, ``param:<name>`` columns, criterion, mean, sd and ``resample:<i>`` (the score on
    each resample or fold). Empty when no job stored a table (``missing_folds_lines`` says why)."""
    picks = picks_frame(run)
    frames = [_job_folds(run.selection_table(key), key, top) for key in picks.loc[picks["folds_stored"], "job"]]
    frames = [f for f in frames if not f.empty]
    if not frames:
        return pd.DataFrame(columns=[*COORDS, "job", "rank", "point", "chosen", "criterion", "mean", "sd"])
    out = pd.concat(frames, ignore_index=True)
    params = [c for c in out.columns if c.startswith(PARAM)]
    resamples = sorted((c for c in out.columns if c.startswith(RESAMPLE)), key=lambda c: int(c[len(RESAMPLE):]))
    return out[[*COORDS, "job", "rank", "point", "chosen", *params, "criterion", "mean", "sd", *resamples]]


def _job_folds(table: pd.DataFrame, key: str, top: int) -> pd.DataFrame:
    """One job's ``folds_frame`` rows from its selection table."""
    if table.empty:
        return table
    scores = table.pivot(index="point", columns="resample", values="score")
    with np.errstate(invalid="ignore"):
        mean, sd = scores.mean(axis=1), scores.std(axis=1, ddof=1 if scores.shape[1] > 1 else 0)
    order = mean.sort_values(kind="stable").index.to_list()
    chosen = set(table.loc[table["chosen"], "point"])
    keep = [p for i, p in enumerate(order) if i < top or p in chosen]
    first = table.drop_duplicates("point").set_index("point")
    params = [c for c in table.columns if c.startswith(PARAM) and first[c].map(_present).any()]
    rows = first.loc[keep, [*COORDS, *params, "criterion"]].reset_index()
    rows.insert(len(COORDS), "job", key)
    rows.insert(len(COORDS) + 1, "rank", [order.index(p) + 1 for p in keep])
    rows.insert(len(COORDS) + 3, "chosen", [p in chosen for p in keep])
    rows["mean"], rows["sd"] = mean.loc[keep].to_numpy(), sd.loc[keep].to_numpy()
    for r in scores.columns:
        rows[f"{RESAMPLE}{int(r)}"] = scores.loc[keep, r].to_numpy()
    return rows


RESAMPLED = {"bootstrap": "bootstrap resamples", "kfold": "folds", "validation": "validation part"}
"""Selection kind -> what its resamples are called (the ``r<i>`` columns of ``folds_text``)."""


def folds_text(folds: pd.DataFrame, kind: str | None = None) -> str:
    """The term text of ``folds_frame``: one block per job, its best points ranked (``*`` marks the selected one);
    ``kind`` (the run's selection kind) names the resamples."""
    from enginebench.results.term import note_text

    word = RESAMPLED.get(str(kind), "resamples or folds")
    blocks = []
    for key, group in folds.groupby("job", sort=False):
        first = group.iloc[0]
        resamples = [c for c in group.columns if c.startswith(RESAMPLE) and group[c].map(_present).any()]
        shown = resamples[:TERM_RESAMPLES]
        more = f"; the first {len(shown)} shown, --format csv gives all" if len(resamples) > len(shown) else ""
        head = (f"{first['method']} {first['target']} window {value_text(first['window'])} {first['split']} "
                f"repetition {first['repetition']} ({first['criterion']} on {len(resamples)} {word}{more}; "
                f"* = selected):")
        table = group.assign(rank=[f"{'*' if c else ' '}{r}" for c, r in zip(group["chosen"], group["rank"])])
        columns = ["rank", "point", *[c for c in group.columns if c.startswith(PARAM) and group[c].map(_present).any()],
                   "mean", "sd", *shown]
        text = _display(table, columns).rename(columns=lambda c: c.replace(RESAMPLE, "r", 1))
        blocks.append(note_text([head]) + _grid(text).rstrip())
    return "\n\n".join(blocks) + ("\n" if blocks else "")


_WHY = {
    "selected": "selected in a run made before selection tables were stored, which keeps no per-fold scores; "
                "run the experiment again to get them",
    "fixed": "nothing scored (a one-point grid or selection kind 'none')",
    "none": "nothing to select",
    "failed": "failed before choosing",
}


def missing_folds_lines(picks: pd.DataFrame) -> list[str]:
    """One line per method (x how) whose jobs have no stored selection table, with how many and why."""
    missing = picks[~picks["folds_stored"].astype(bool)]
    return [f"{method} ({len(group)} job{'s' if len(group) > 1 else ''}): {_WHY[how]}"
            for (method, how), group in missing.groupby(["method", "how"], sort=False, dropna=False)]
