"""Export a stored run to an MLflow tracking store (optional dependency: ``pip install "enginebench[mlflow]"``).

One enginebench run becomes one MLflow run (named by the run id) in an MLflow experiment
named after the enginebench experiment, holding:

- params: the resolved config flattened to dotted keys (``config.split.kind``), and the
  hyperparameters each job selected, one param per (target, window, split, method,
  hyperparameter) whose value is the JSON list over repetitions 0, 1, ...;
- metrics, per (split, target, window, method, metric), under the key
  ``SPLIT/TARGET/wWINDOW/METHOD/METRIC/``: the mean over repetitions (as in the comparison
  table) as ``.../mean``, its interval as ``.../ci_low`` and ``.../ci_high``, and each
  repetition's value as ``.../repetitions`` with step = repetition (a file store keeps a
  key as a file, so no key is a prefix of another); numeric selected hyperparameters also as
  ``selected/TARGET/wWINDOW/SPLIT/METHOD/NAME`` with step = repetition;
- artefacts: config.toml, environment.json, run.json, the long table (table.csv), the
  selected hyperparameters per job (selected_hyperparameters.csv) and, on request, the
  HTML report under ``report/``.

MLflow keys allow letters, digits, ``_ - . : /`` and spaces; other characters of method
names (``moe[ideal]``) become ``_``, and a clash between two sanitised keys is refused.
MLflow 3 refuses a local file store unless ``MLFLOW_ALLOW_FILE_STORE`` is set; a
``file:`` URI (or a plain folder) asked for explicitly sets it for this process unless
the variable is already set.
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import pandas as pd

from enginebench.errors import EngineBenchError
from enginebench.results import tables
from enginebench.results.store import Run

INSTALL_HINT = 'pip install "enginebench[mlflow]"'
MAX_PARAM_CHARS = 6000
"""MLflow's limit on a param value; longer values are cut (the csv artefact holds them whole)."""
BATCH = 900
"""Entities per log_batch call (MLflow accepts at most 1000 metrics, 100 params)."""
PARAM_BATCH = 100
_KEY_BAD = re.compile(r"[^\w\-. :/]")


class MissingDependency(EngineBenchError):
    """An optional dependency needed by the command is not installed."""


@dataclass
class ExportResult:
    """Where the run went and how much was logged."""

    tracking_uri: str
    experiment_id: str
    mlflow_run_id: str
    params: dict[str, str] = field(default_factory=dict)
    n_metric_values: int = 0
    artifacts: list[str] = field(default_factory=list)


def import_mlflow():
    """The ``mlflow`` module and ``MlflowClient``, or a MissingDependency saying how to install them."""
    try:
        import mlflow
        from mlflow.tracking import MlflowClient
    except ImportError:
        raise MissingDependency(f"MLflow export needs the mlflow package, which is not installed; {INSTALL_HINT}") from None
    return mlflow, MlflowClient


def sanitize_key(text: str) -> str:
    """An MLflow-safe metric/param key: characters MLflow refuses become '_'."""
    return _KEY_BAD.sub("_", text)


def resolve_uri(uri: str) -> str:
    """A plain folder becomes a ``file:`` URI; other URIs pass through unchanged."""
    if re.match(r"^[A-Za-z][A-Za-z0-9+.-]*:", uri) and not re.match(r"^[A-Za-z]:[\\/]", uri):
        return uri
    return Path(uri).expanduser().resolve().as_uri()


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
    return f"w{float(w):g}"


def metric_key(split: str, target: str, window: float, method: str, metric: str) -> str:
    """The MLflow key prefix of one summary cell: ``SPLIT/TARGET/wWINDOW/METHOD/METRIC`` (sanitised)."""
    return sanitize_key(f"{split}/{target}/{_window(window)}/{method}/{metric}")


def selected_frame(run: Run) -> pd.DataFrame:
    """One row per (job, hyperparameter) of the finished jobs: target, window, split, method, repetition, name, value."""
    rows = []
    for key in sorted(run.finished_jobs()):
        meta = run.job_meta(key)
        if meta.get("status") != "ok":
            continue
        split = key.split("__")[2] if key.count("__") >= 4 else ""
        for name, value in flatten(meta.get("params", {}) or {}).items():
            rows.append({"target": meta.get("target"), "window": float(meta.get("window", 0.0)), "split": split,
                         "method": meta.get("method"), "repetition": int(meta.get("repetition", -1)), "name": name,
                         "value": json.dumps(value, default=str)})
    return pd.DataFrame(rows, columns=["target", "window", "split", "method", "repetition", "name", "value"])


def _repetition_values(raw: pd.DataFrame) -> pd.DataFrame:
    """The per-repetition rows behind the summary: finished, scored, finite, with paired skill rows added."""
    ok = raw[(raw["status"] == "ok") & (raw["split"] != "-") & ~raw["metric"].isin(["n", "n_segments"])]
    return tables.with_skill(ok.dropna(subset=["value"]))


def _checked(keys: Iterable[tuple[str, str]]) -> None:
    seen: dict[str, str] = {}
    for safe, original in keys:
        if safe in seen and seen[safe] != original:
            raise EngineBenchError(f"MLflow keys clash after sanitising: {seen[safe]!r} and {original!r} both become "
                                   f"{safe!r}; rename one of the methods")
        seen[safe] = original


def export_run(
    run: Run,
    tracking_uri: str,
    *,
    experiment: str | None = None,
    interval: str | None = None,
    report_dir: str | Path | None = None,
) -> ExportResult:
    """Log ``run`` to the MLflow tracking store at ``tracking_uri`` as a new MLflow run; see the module docstring.

    ``report_dir``: a folder written by ``write_report``, logged under ``report/``.
    """
    uri = resolve_uri(tracking_uri)
    if uri.startswith("file:"):
        os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
    _, MlflowClient = import_mlflow()
    from mlflow.entities import Metric, Param
    from mlflow.exceptions import MlflowException

    cfg, info, env = run.config(), run.info(), run.environment()
    raw = run.metrics()
    summary = tables.summarize(raw, interval=interval or cfg.get("interval", "t"))
    per_rep = _repetition_values(raw)
    selected = selected_frame(run)

    params: dict[str, str] = {}
    origin: list[tuple[str, str]] = []
    for k, v in flatten(cfg).items():
        key = sanitize_key(f"config.{k}")
        origin.append((key, f"config.{k}"))
        params[key] = _param_value(v)
    for (target, window, split, method, name), group in selected.groupby(
            ["target", "window", "split", "method", "name"], sort=True):
        raw_key = f"selected/{target}/{_window(window)}/{split}/{method}/{name}"
        key = sanitize_key(raw_key)
        origin.append((key, raw_key))
        values = [json.loads(v) for v in group.sort_values("repetition")["value"]]
        params[key] = _param_value(values)

    now = int(time.time() * 1000)
    metrics: list[tuple[str, float, int]] = []
    for r in summary.itertuples(index=False):
        base = metric_key(r.split, r.target, r.window, r.method, r.metric)
        origin.append((base, f"{r.split}/{r.target}/{_window(r.window)}/{r.method}/{r.metric}"))
        for suffix, value in (("/mean", r.mean), ("/ci_low", r.ci_low), ("/ci_high", r.ci_high)):
            if value is not None and math.isfinite(float(value)):
                metrics.append((base + suffix, float(value), 0))
    for r in per_rep.itertuples(index=False):
        if not math.isfinite(float(r.value)):
            continue
        metrics.append((metric_key(r.split, r.target, r.window, r.method, r.metric) + "/repetitions", float(r.value),
                        int(r.repetition)))
    for r in selected.itertuples(index=False):
        value = json.loads(r.value)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            metrics.append((sanitize_key(f"selected/{r.target}/{_window(r.window)}/{r.split}/{r.method}/{r.name}"),
                            float(value), int(r.repetition)))
    _checked(origin)

    tags = {"enginebench.run_id": run.id, "enginebench.config_hash": str(info.get("config_hash", "")),
            "enginebench.dataset": str(cfg.get("dataset", "")), "enginebench.status": str(info.get("status", "")),
            "enginebench.mode": str(cfg.get("mode", ""))}
    if env.get("git_commit"):
        tags["mlflow.source.git.commit"] = str(env["git_commit"])
    name = experiment or str(cfg.get("name") or info.get("name") or run.id)
    try:
        client = MlflowClient(tracking_uri=uri)
        found = client.get_experiment_by_name(name)
        experiment_id = found.experiment_id if found is not None else client.create_experiment(name)
        mlrun = client.create_run(experiment_id, run_name=run.id, tags=tags)
        run_id = mlrun.info.run_id
        items = list(params.items())
        for i in range(0, len(items), PARAM_BATCH):
            client.log_batch(run_id, params=[Param(k, v) for k, v in items[i:i + PARAM_BATCH]])
        for i in range(0, len(metrics), BATCH):
            client.log_batch(run_id, metrics=[Metric(k, v, now, s) for k, v, s in metrics[i:i + BATCH]])
        artifacts = []
        for fname in ("config.toml", "environment.json", "run.json"):
            if (run.path / fname).is_file():
                client.log_artifact(run_id, str(run.path / fname))
                artifacts.append(fname)
        with tempfile.TemporaryDirectory(prefix="enginebench-mlflow-") as tmp:
            (Path(tmp) / "table.csv").write_text(tables.to_csv(summary), encoding="utf-8")
            selected.to_csv(Path(tmp) / "selected_hyperparameters.csv", index=False)
            for fname in ("table.csv", "selected_hyperparameters.csv"):
                client.log_artifact(run_id, str(Path(tmp) / fname))
                artifacts.append(fname)
        if report_dir is not None:
            client.log_artifacts(run_id, str(report_dir), artifact_path="report")
            artifacts.append("report/")
        client.set_terminated(run_id, "FINISHED" if info.get("status") == "finished" else "KILLED")
    except MlflowException as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EngineBenchError(f"MLflow ({uri}): {first}") from None
    return ExportResult(tracking_uri=uri, experiment_id=experiment_id, mlflow_run_id=run_id, params=params,
                        n_metric_values=len(metrics), artifacts=artifacts)
