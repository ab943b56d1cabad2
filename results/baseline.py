"""Published baselines: the file format, and making, writing, finding, reading and validating them.

A baseline is a JSON file (``enginebench publish RUN -o FILE`` writes it; the project
keeps those of its built-in experiments in ``results/published/``)::

    {
      "format": "enginebench-baseline",      fixed marker
      "version": 1,                          format version
      "experiment": "gas-turbine-nox-quick", the experiment's name
      "config_hash": "<sha256>",             ExperimentSpec.config_hash() of the run
      "dataset": "gas-turbine-emissions",    the experiment's dataset (name or file)
      "dataset_variant": "",
      "dataset_hash": "<sha256>" | null,     content hash of the dataset, if available
      "interval": "t",                       t (Student-t) | bootstrap (percentile)
      "level": 0.95,                         confidence level of the intervals
      "source": {"run": ..., "created": ..., "git_commit": ..., "enginebench": ...},
      "reproducibility": {                   optional: how the entries' rtol were measured
        "procedure": "...", "safety_factor": 10,
        "reruns": [{"name": "avx2-cpu", "description": ..., "env": {...}, "workers": ...,
                    "dataset_hash": ..., "max_rel_diff": {"krls": 3e-12, "pm": 2.1e-4}}, ...],
        "max_rel_diff": {"krls": 3e-12, "pm": 2.1e-4}, "rtol": {"krls": 3e-11, "pm": 2.1e-3},
        "machine": {"cpu": ..., "numpy": ..., "scipy": ...}
      },
      "entries": [                           one per (target, mode, window, method, split, metric)
        {"target": "NOX", "mode": "static", "window": 0.0, "method": "krls", "split": "test",
         "metric": "mae", "mean": 2.51, "ci_low": 2.47, "ci_high": 2.55, "n_repeats": 30,
         "n_failed": 0, "lower_is_better": true, "rtol": 3e-11},
        ...
      ]
    }

``ci_low``/``ci_high`` are null where no interval exists (one repetition); ``n_failed``
(failed repetitions of that method) is optional and defaults to 0. ``rtol`` (optional,
default ``ROUNDING_RTOL``) is the relative numeric tolerance the value needs to be
reproduced on another machine: measured when publishing by rerunning the experiment under
the numerics of other CPUs and BLAS threading (``results/reproduce.py``), per method,
times a safety factor. The dataset hash is taken from the run when it records one
(``dataset_hash`` in run.json), else from the Parquet footer of the dataset file the
run's config names (the cached built-in in the data home, or the ``.parquet`` file),
else null; that lookup is the caller's (``experiments.run_dataset``), results/ reads no
dataset.

The guard (``results/guard.py``) checks a run against a loaded baseline; this module is
only the file: what it holds and how it is written and read back, checked.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from enginebench.declare import Declaration, Invalid, anything, flag, listing, number, table, text, whole
from enginebench.errors import DataError
from enginebench.results.compare import JOIN, lower_is_better
from enginebench.results.output import write_output
from enginebench.results.reproduce import ROUNDING_RTOL
from enginebench.results.summary import summarize

FORMAT = "enginebench-baseline"
VERSION = 1
_STR_KEYS = ("target", "mode", "method", "split", "metric")


class BaselineError(DataError):
    """A baseline file that is missing or malformed."""


def published_dir() -> Path:
    """The folder of the baselines that ship with the package (results/published)."""
    return Path(__file__).resolve().parent / "published"


# -- writing ------------------------------------------------------------------------

def _finite_or_none(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def baseline_from_summary(summary: pd.DataFrame, *, experiment: str, config_hash: str, dataset: str,
                          dataset_variant: str = "", dataset_hash: str | None = None, interval: str = "t",
                          level: float = 0.95, source: dict[str, Any] | None = None,
                          reproducibility: dict[str, Any] | None = None) -> dict[str, Any]:
    """A baseline document from a ``tables.summarize`` frame (one entry per summary row).

    With ``reproducibility`` (``results.reproduce.measure``) each entry gets its method's
    measured ``rtol`` and the record is kept in the document.
    """
    rows = summary.sort_values(["target", "mode", "window", "split", "method", "metric"], kind="stable")
    rtol = (reproducibility or {}).get("rtol", {})
    entries = [{
        "target": str(r.target), "mode": str(r.mode), "window": float(r.window), "method": str(r.method),
        "split": str(r.split), "metric": str(r.metric), "mean": float(r.mean),
        "ci_low": _finite_or_none(r.ci_low), "ci_high": _finite_or_none(r.ci_high),
        "n_repeats": int(r.n_repeats), "n_failed": int(r.n_failed), "lower_is_better": lower_is_better(str(r.metric)),
        **({"rtol": float(rtol[str(r.method)])} if str(r.method) in rtol else {}),
    } for r in rows.itertuples()]
    doc = {"format": FORMAT, "version": VERSION, "experiment": experiment, "config_hash": config_hash,
           "dataset": dataset, "dataset_variant": dataset_variant, "dataset_hash": dataset_hash,
           "interval": interval, "level": level, "source": source or {}}
    if reproducibility is not None:
        doc["reproducibility"] = reproducibility
    return {**doc, "entries": entries}


def recorded_dataset_hash(run) -> str | None:
    """The content hash of the run's dataset as the run recorded it (None for runs made before it was recorded)."""
    recorded = run.info().get("dataset_hash")
    return str(recorded) if recorded else None


def make_baseline(run, *, interval: str | None = None, metric_names: Sequence[str] | None = None,
                  measure_tolerance: bool = False, perturbations=None, progress=None,
                  dataset_hash: str | None = None, generated_dataset: bool = False) -> dict[str, Any]:
    """The baseline of a stored run (``results.store.Run``), optionally restricted to some metrics.

    ``measure_tolerance`` reruns the experiment under other machines' numerics
    (``results.reproduce``) and records each method's measured ``rtol``. ``dataset_hash``
    (default: the one the run recorded) and ``generated_dataset`` (a synthetic built-in,
    generated again by the reruns) come from the caller: results/ does not read datasets
    (``experiments.run_dataset.run_dataset`` looks them up).
    """
    from enginebench import __version__

    cfg, info, env = run.config(), run.info(), run.environment()
    interval = interval or cfg.get("interval", "t")
    summary = summarize(run.metrics(), interval=interval)
    if metric_names:
        unknown = sorted(set(metric_names) - set(summary["metric"]))
        if unknown:
            raise DataError(f"run {run.id} has no metric(s) {', '.join(unknown)}; it has {', '.join(sorted(set(summary['metric'])))}")
        summary = summary[summary["metric"].isin(metric_names)]
    source = {"run": run.id, "created": info.get("created"), "published": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
              "status": info.get("status"), "git_commit": env.get("git_commit"), "enginebench": __version__}
    reproducibility = None
    if measure_tolerance:
        from enginebench.results.reproduce import measure

        reproducibility = measure(run, summary, interval=interval, perturbations=perturbations, progress=progress,
                                  generated_dataset=generated_dataset)
    return baseline_from_summary(summary, experiment=str(cfg.get("name", info.get("name", ""))),
                                 config_hash=str(info.get("config_hash", "")), dataset=str(cfg.get("dataset", "")),
                                 dataset_variant=str(cfg.get("dataset_variant", "") or ""),
                                 dataset_hash=dataset_hash or recorded_dataset_hash(run),
                                 interval=interval, source=source, reproducibility=reproducibility)


def write_baseline(baseline: dict[str, Any], path: str | Path) -> Path:
    """Write a baseline as JSON, one entry per line (small diffs when a baseline is republished)."""
    path = Path(path)
    head = {k: v for k, v in baseline.items() if k != "entries"}
    lines = ["{"] + [f"  {json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()] + ['  "entries": [']
    entries = [f"    {json.dumps(e, allow_nan=False)}" for e in baseline["entries"]]
    lines += [",\n".join(entries)] if entries else []
    lines += ["  ]", "}"]
    return write_output(path, "\n".join(lines) + "\n")


# -- reading ------------------------------------------------------------------------

def resolve_baseline(ref: str | Path) -> Path:
    """A baseline file path, or the name of a published baseline (``gas-turbine-nox-quick``)."""
    path = Path(ref)
    if path.is_file():
        return path
    if path.parent == Path(".") and (published_dir() / f"{path.stem}.json").is_file():
        return published_dir() / f"{path.stem}.json"
    names = sorted(p.stem for p in published_dir().glob("*.json"))
    raise BaselineError(f"baseline {ref}: file not found; 'enginebench publish RUN -o FILE' writes one"
                        f" (published: {', '.join(names) or 'none'})")


def _bad(path: Path, where: str, what: str) -> BaselineError:
    return BaselineError(f"baseline {path}: {where} {what}; re-create it with 'enginebench publish RUN -o {path}'")


def _string(value: Any) -> str:
    if not isinstance(value, str):
        raise Invalid("needs {name} as a string, got {value}")
    return value


def _rtol(value: Any) -> float:
    return max(float(value), ROUNDING_RTOL)


NUMBER = "{name} must be a finite number, got {value}"
NUMBER_OR_NULL = "{name} must be a finite number or null, got {value}"
TEXT = "{name} must be a non-empty string, got {value}"
TOP = Declaration(
    anything("format", FORMAT, "fixed marker"),
    anything("version", VERSION, "format version"),
    anything("experiment", None, "the experiment's name", check=_string, type_label="str"),
    anything("config_hash", None, "ExperimentSpec.config_hash() of the run", check=_string, type_label="str"),
    anything("interval", None, "t (Student-t) or bootstrap (percentile)", check=_string, type_label="str"),
    table("reproducibility", None, "how the entries' rtol were measured", nullable=True,
          message="{name} must be an object (how the tolerances were measured), got {value}"),
    listing("entries", None, "one published value per (target, mode, window, method, split, metric)",
            message="{name} must be a non-empty list of published values"),
)
"""A baseline's checked top-level keys (others, such as ``source``, are free)."""
ENTRY_NAMES = Declaration(*(text(k, None, f"the entry's {k}", message=TEXT) for k in _STR_KEYS))
ENTRY = Declaration(
    number("window", None, "window length", unit="s", message=NUMBER),
    number("mean", None, "the published mean", message=NUMBER),
    number("ci_low", None, "lower end of the interval; null where none", nullable=True, message=NUMBER_OR_NULL),
    number("ci_high", None, "upper end of the interval; null where none", nullable=True, message=NUMBER_OR_NULL),
    whole("n_repeats", None, "repetitions behind the mean", low=1,
          message="{name} must be a positive integer, got {value}"),
    whole("n_failed", 0, "failed repetitions", low=0, message="{name} must be a non-negative integer, got {value}"),
    number("rtol", None, "relative reproduction tolerance of the value (default ROUNDING_RTOL)", low=0, high=1,
           high_open=True, check=_rtol, message="{name} must be a number in [0, 1) (the value's relative "
                                                "reproduction tolerance), got {value}"),
    flag("lower_is_better", None, "direction of the metric"),
)
"""A baseline entry's keys besides the names (``_STR_KEYS``)."""


def _checked(path: Path, where: str, declared: Declaration, values: dict[str, Any]) -> dict[str, Any]:
    """``values`` (every declared key; an absent one takes its default, None where required) checked."""
    full = {k: values.get(k, declared[k].default) for k in declared.names()}
    return declared.validate(full, "", lambda line: _bad(path, where, line), name="key {key!r}")


def load_baseline(path: str | Path) -> dict[str, Any]:
    """Read and validate a baseline file; any problem is one BaselineError naming the file, entry and key."""
    path = resolve_baseline(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise _bad(path, "is not valid JSON:", f"{exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BaselineError(f"baseline {path}: cannot be read ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise _bad(path, "the top level", f"is not an enginebench baseline (it needs \"format\": \"{FORMAT}\")")
    if doc.get("version") != VERSION:
        raise _bad(path, "key 'version'", f"is {doc.get('version')!r}; this enginebench reads version {VERSION}")
    top = {k: doc.get(k) for k in ("experiment", "config_hash", "interval", "entries")}
    if "reproducibility" in doc:
        top["reproducibility"] = doc["reproducibility"]
    TOP.validate(top, "", lambda line: BaselineError(f"baseline {path}: {line}; re-create it with 'enginebench "
                                                     f"publish RUN -o {path}'"), name="key {key!r}")
    clean, seen = [], set()
    for i, e in enumerate(doc["entries"]):
        where = f"entry {i}"
        if not isinstance(e, dict):
            raise _bad(path, where, f"must be an object, got {e!r}")
        row = _checked(path, where, ENTRY_NAMES, e)
        where = f"entry {i} ({e['method']} {e['metric']}, {e['target']}, {e['split']})"
        rest = _checked(path, where, ENTRY, {**e, "rtol": e.get("rtol", ROUNDING_RTOL)})
        row.update(rest, **{k: float("nan") if rest[k] is None else float(rest[k])
                            for k in ("window", "mean", "ci_low", "ci_high")})
        if row["ci_low"] > row["mean"] or row["ci_high"] < row["mean"]:
            raise _bad(path, where, f"has an interval [{e['ci_low']}, {e['ci_high']}] that does not contain its mean {e['mean']}")
        key = tuple(row[k] for k in JOIN)
        if key in seen:
            raise _bad(path, where, "repeats an earlier entry with the same target, mode, window, method, split and metric")
        seen.add(key)
        clean.append(row)
    return {**doc, "entries": clean, "path": str(path)}
