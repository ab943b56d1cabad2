"""What a stored run becomes in MLflow: the parent and child runs' params, tags and metrics.

Computed from the stored run alone, without MLflow; ``mlflow_export`` logs it (talking to
the tracking store: destination checks, logging, replacing). Kept apart so the layout can be
built and tested without the optional dependency.

Layout, in the MLflow experiment named after the enginebench experiment (or ``experiment=``):

- one **parent** MLflow run per enginebench run, named ``NAME [RUN_ID]``; tags
  ``enginebench.run_id``, ``enginebench.experiment``, ``enginebench.dataset``,
  ``enginebench.config_hash``, ``enginebench.status``, ``enginebench.mode``, the git commit
  (``mlflow.source.git.commit``) and the enginebench/Python versions; params: the resolved
  config flattened to dotted keys (``mode``, ``windows``, ``repetitions``, ``split.kind``,
  ``selection.kind``, ``method_options.krls.gamma_grid``...); metrics ``n_jobs``,
  ``finished_jobs``, ``failed_jobs``; artefacts config.toml, environment.json, run.json, the
  long table (table.csv), the selected hyperparameters per job (selected_hyperparameters.csv)
  and, on request, the HTML report under ``report/``;
- one **child** run per method, nested under the parent (tag ``mlflow.parentRunId``), named
  by the method; params ``method``, ``family``, ``dataset`` (the name the tables show),
  ``mode`` and the selected hyperparameters; metrics from the comparison table.

Keys line up across the children, so MLflow's compare view puts methods side by side.
When the run has one (target, window, scored part), metrics are plain: ``mae``,
``mae_ci_low``, ``mae_ci_high``, ``n_failed``, ``n_diverged``; otherwise each carries the
cell, ``mae/TARGET/dWINDOW/PART`` (``mae_ci_low/TARGET/dWINDOW/PART``...). Every child gets
every key of the run: a cell a method has no number for (all repetitions failed, an
interval that does not exist) is logged as NaN, as the table shows it.

Selected hyperparameters: a job's pick can differ between repetitions, so a child logs per
(target, window, split) and hyperparameter the most frequent pick (a tie goes to the pick
of the earliest repetition), as ``gamma`` when the run has one (target, window, split),
else ``gamma/TARGET/dWINDOW`` (``.../SPLIT`` added with several splits); the tag
``enginebench.picks.KEY`` holds how often each value was picked (JSON ``{value: count}``).
A pick whose name is one of the fixed params (``method``...) is logged as ``param.NAME``.

Keys follow MLflow's rules: letters, digits, ``_ - . /`` and spaces (other characters, and
``/`` inside a name, become ``_``; ``:`` too, which Windows refuses), at most 250
characters (a longer key is cut and ends in ``~`` and 8 hex digits of its hash); a clash
between two sanitised keys is refused.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import pandas as pd

from enginebench.errors import EngineBenchError
from enginebench.results import tables
from enginebench.results.run_folder import Run

MAX_PARAM_CHARS = 6000
"""MLflow's limit on a param value; longer values are cut (the csv artefact holds them whole)."""
MAX_TAG_CHARS = 8000
MAX_KEY_CHARS = 250
"""MLflow's limit on a param, metric or tag key."""
FIXED_PARAMS = ("method", "family", "dataset", "mode")
"""The params every child run has; a selected hyperparameter of the same name becomes ``param.NAME``."""
_KEY_BAD = re.compile(r"[^\w\-. /]")
_PART_BAD = re.compile(r"[^\w\-. ]")


class ExportError(EngineBenchError):
    """The MLflow tracking store cannot be used, refused a write, or already holds the run."""


@dataclass
class ChildRun:
    """What one method's child run holds."""

    method: str
    params: dict[str, str]
    tags: dict[str, str]
    metrics: dict[str, float]
    status: str


@dataclass
class Layout:
    """The MLflow runs one enginebench run becomes: the parent's content and one child per method."""

    run_name: str
    params: dict[str, str]
    tags: dict[str, str]
    metrics: dict[str, float]
    status: str
    children: list[ChildRun]
    table: pd.DataFrame = field(repr=False, default_factory=pd.DataFrame)
    """The summary the metrics come from (``tables.summarize``), logged as table.csv."""
    selected: pd.DataFrame = field(repr=False, default_factory=pd.DataFrame)
    """Every job's selected hyperparameters (``selected_frame``), logged as selected_hyperparameters.csv."""



def sanitize_key(text: str) -> str:
    """An MLflow-safe metric/param key: characters MLflow refuses become '_'."""
    return _KEY_BAD.sub("_", text)


def key_part(text: Any) -> str:
    """One component of a key: characters MLflow refuses, and '/', become '_'; '', '.' and '..' become '_'."""
    part = _PART_BAD.sub("_", str(text))
    return "_" if part in ("", ".", "..") else part


def mlflow_key(*parts: Any) -> str:
    """Components joined by '/', each made safe; a key over 250 characters is cut and ends in '~' + a hash."""
    key = "/".join(key_part(p) for p in parts)
    if len(key) <= MAX_KEY_CHARS:
        return key
    digest = hashlib.sha256(key.encode("utf-8")).hexdigest()[:8]
    return f"{key[: MAX_KEY_CHARS - 9].rstrip('/')}~{digest}"



def flatten(obj: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts to dotted keys; lists and scalars are leaves."""
    if isinstance(obj, dict):
        out: dict[str, Any] = {}
        for k, v in obj.items():
            out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: obj}


def _param_value(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    return text if len(text) <= MAX_PARAM_CHARS else text[: MAX_PARAM_CHARS - 3] + "..."


def _window(w: float) -> str:
    return f"d{float(w):g}"


def registry_family(method: str) -> str | None:
    """The family of the registered method class named ``method``, or None when it cannot be imported."""
    try:
        from enginebench import registry

        return str(registry.get(method).family)
    except Exception:  # noqa: BLE001 - unknown, broken or unimportable: the run's stored family is used
        return None


def job_records(run: Run) -> pd.DataFrame:
    """One row per finished job: method, family, target, window, split, repetition, status, params (flattened dict)."""
    rows = []
    for key, meta in sorted(run.job_metas().items()):
        parts = key.split("__")  # runs written before the metadata named the split: the key's third part
        split = meta.get("split", parts[2] if len(parts) >= 5 else "")
        rows.append({"method": str(meta.get("method")), "family": meta.get("family"), "target": str(meta.get("target")),
                     "window": float(meta.get("window", 0.0)), "split": str(split),
                     "repetition": int(meta.get("repetition", -1)), "status": meta.get("status"),
                     "params": flatten(meta.get("params", {}) or {}) if meta.get("status") == "ok" else {}})
    return pd.DataFrame(rows, columns=["method", "family", "target", "window", "split", "repetition", "status",
                                       "params"])


def selected_frame(run: Run, jobs: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per (successful job, hyperparameter): target, window, split, method, repetition, name, value (JSON)."""
    jobs = job_records(run) if jobs is None else jobs
    rows = [{"target": j.target, "window": j.window, "split": j.split, "method": j.method, "repetition": j.repetition,
             "name": name, "value": json.dumps(value, default=str)}
            for j in jobs.itertuples(index=False) for name, value in j.params.items()]
    return pd.DataFrame(rows, columns=["target", "window", "split", "method", "repetition", "name", "value"])


def most_frequent_picks(selected: pd.DataFrame) -> pd.DataFrame:
    """Per (method, target, window, split, name): the most frequent value (ties: the earliest repetition's pick).

    Columns: method, target, window, split, name, value (JSON), count, of (repetitions
    with a pick) and counts (JSON ``{value: count}``, most frequent first).
    """
    cols = ["method", "target", "window", "split", "name"]
    if selected.empty:
        return pd.DataFrame(columns=cols + ["value", "count", "of", "counts"])
    tally = (selected.groupby(cols + ["value"], sort=False)
             .agg(count=("repetition", "size"), first=("repetition", "min")).reset_index()
             .sort_values(["count", "first"], ascending=[False, True], kind="stable"))
    rows = []
    for key, group in tally.groupby(cols, sort=True):
        counts = {_param_value(json.loads(v)): int(n) for v, n in zip(group["value"], group["count"])}
        rows.append((*key, group["value"].iloc[0], int(group["count"].iloc[0]), int(group["count"].sum()),
                     json.dumps(counts)))
    return pd.DataFrame(rows, columns=cols + ["value", "count", "of", "counts"])


def _families(jobs: pd.DataFrame, raw: pd.DataFrame, family_of: Callable[[str], str | None]) -> dict[str, str]:
    stored: dict[str, str] = {}
    if "family" in raw.columns:
        stored.update(raw.dropna(subset=["family"]).groupby("method")["family"].first().astype(str).to_dict())
    stored.update(jobs.dropna(subset=["family"]).groupby("method")["family"].first().astype(str).to_dict())
    methods = set(jobs["method"]) | set(raw["method"].astype(str))
    return {m: family_of(m) or stored.get(m, "") for m in methods}


def _checked(keys: Iterable[tuple[str, str]], where: str) -> None:
    seen: dict[str, str] = {}
    for safe, original in keys:
        if safe in seen and seen[safe] != original:
            raise ExportError(f"MLflow keys clash after sanitising in {where}: {seen[safe]!r} and {original!r} both "
                              f"become {safe!r}; rename one of them")
        seen[safe] = original


def _cell_metrics(summary: pd.DataFrame) -> dict[str, dict[str, float]]:
    """Method -> {metric key: value} from the summary, every child with every key (NaN where a method has none)."""
    cells = summary[["target", "window", "split"]].drop_duplicates()
    single = len(cells) == 1
    suffix = (lambda t, w, s: ()) if single else (lambda t, w, s: (t, _window(w), s))  # noqa: E731
    values: dict[str, dict[str, float]] = {m: {} for m in summary["method"].astype(str).unique()}
    origin: list[tuple[str, str]] = []

    def put(method: str, name: str, t: str, w: float, s: str, value: Any) -> None:
        key = mlflow_key(name, *suffix(t, w, s))
        origin.append((key, "/".join([name, *map(str, suffix(t, w, s))])))
        values[method][key] = float(value) if value is not None and not pd.isna(value) else math.nan

    for r in summary[summary["metric"] != "diverged"].itertuples(index=False):  # counted by n_diverged
        put(r.method, r.metric, r.target, r.window, r.split, r.mean)
        put(r.method, f"{r.metric}_ci_low", r.target, r.window, r.split, r.ci_low)
        put(r.method, f"{r.metric}_ci_high", r.target, r.window, r.split, r.ci_high)
    counts = summary.groupby(["method", "target", "window", "split"], sort=True)[["n_failed", "n_diverged"]].max()
    for (method, t, w, s), r in counts.iterrows():
        put(method, "n_failed", t, w, s, r["n_failed"])
        put(method, "n_diverged", t, w, s, r["n_diverged"])
    _checked(origin, "the metric keys")
    every = sorted({k for v in values.values() for k in v})
    return {m: {k: v.get(k, math.nan) for k in every} for m, v in values.items()}


def _pick_params(picks: pd.DataFrame, jobs: pd.DataFrame) -> dict[str, tuple[dict[str, str], dict[str, str]]]:
    """Method -> (params, tags) of its selected hyperparameters (see the module docstring for the keys)."""
    cells = jobs[["target", "window", "split"]].drop_duplicates()
    single, one_split = len(cells) == 1, cells["split"].nunique() <= 1
    out: dict[str, tuple[dict[str, str], dict[str, str]]] = {}
    origin: dict[str, list[tuple[str, str]]] = {}
    for p in picks.itertuples(index=False):
        name = f"param.{p.name}" if p.name in FIXED_PARAMS else p.name
        where = () if single else (p.target, _window(p.window)) if one_split else (p.target, _window(p.window), p.split)
        key = mlflow_key(name, *where)
        params, tags = out.setdefault(p.method, ({}, {}))
        origin.setdefault(p.method, []).append((key, "/".join(map(str, (name, *where)))))
        params[key] = _param_value(json.loads(p.value))
        tags[mlflow_key(f"enginebench.picks.{name}", *where)] = p.counts[:MAX_TAG_CHARS]
    for method, keys in origin.items():
        _checked(keys, f"the selected hyperparameters of {method!r}")
    return out


def build_layout(run: Run, *, interval: str | None = None,
                 family_of: Callable[[str], str | None] = registry_family) -> Layout:
    """The parent and child runs ``run`` becomes (see the module docstring), computed from the stored run alone.

    ``family_of``: a method's family (default: its registered class); None falls back to
    the family the run stored with each job.
    """
    cfg, info, env = run.config(), run.info(), run.environment()
    raw = run.metrics()
    summary = tables.summarize(raw, interval=interval or cfg.get("interval", "t"))
    jobs = job_records(run)
    selected = selected_frame(run, jobs)
    picks = most_frequent_picks(selected)
    families = _families(jobs, raw, family_of)
    metrics = _cell_metrics(summary)
    hyper = _pick_params(picks, jobs)
    dataset = str(summary["dataset"].iloc[0]) if len(summary) else str(cfg.get("dataset", ""))
    mode = str(cfg.get("mode", ""))
    name = str(cfg.get("name") or info.get("name") or run.id)

    params: dict[str, str] = {}
    origin = []
    for k, v in flatten(cfg).items():
        key = mlflow_key(k)
        origin.append((key, k))
        params[key] = _param_value(v)
    _checked(origin, "the config params")
    tags = {"enginebench.run_id": run.id, "enginebench.experiment": name, "enginebench.dataset": dataset,
            "enginebench.config_hash": str(info.get("config_hash", "")),
            "enginebench.status": str(info.get("status", "")), "enginebench.mode": mode}
    if env.get("git_commit"):
        tags["mlflow.source.git.commit"] = str(env["git_commit"])
    for label, value in (("enginebench.version", (env.get("packages") or {}).get("enginebench")),
                         ("enginebench.python", env.get("python"))):
        if value:
            tags[label] = str(value)
    parent_metrics = {k: float(info[k]) for k in ("n_jobs", "finished_jobs", "failed_jobs")
                      if isinstance(info.get(k), (int, float)) and not isinstance(info.get(k), bool)}

    order = [str(m) for m in cfg.get("methods", []) if isinstance(m, str)]
    methods = [m for m in order if m in metrics] + sorted(m for m in metrics if m not in order)
    children = []
    for method in methods:
        p_params, p_tags = hyper.get(method, ({}, {}))
        ok = bool(((jobs["method"] == method) & (jobs["status"] == "ok")).any())
        children.append(ChildRun(
            method=method,
            params={"method": method, "family": families.get(method, ""), "dataset": dataset, "mode": mode, **p_params},
            tags={"enginebench.run_id": run.id, "enginebench.method": method, **p_tags},
            metrics=metrics[method], status="FINISHED" if ok else "FAILED"))
    return Layout(run_name=f"{name} [{run.id}]", params=params, tags=tags, metrics=parent_metrics,
                  status="FINISHED" if info.get("status") == "finished" else "KILLED", children=children,
                  table=summary, selected=selected)
