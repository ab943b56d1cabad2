"""The ``[slurm]`` table of an experiment and ``--slurm KEY=VALUE``: what each method's tasks ask SLURM for.

Kept apart from the executor (``experiments/slurm.py``) so that the spec checks the table
without importing the engine that runs jobs (no circle spec -> slurm -> executors -> ... -> spec).
"""

from __future__ import annotations

import math
import re
from typing import Any, Iterable, Mapping

from enginebench.declare import Declaration, Invalid, anything, choice, listing, text, whole
from enginebench.errors import SpecError

CLUSTERS = ("slurm", "local", "debug")


def _time(value: Any) -> Any:
    """Minutes (a whole number), or SLURM's ``MM``, ``HH:MM:SS``, ``D-HH:MM:SS`` text."""
    if isinstance(value, bool):
        raise Invalid("{name} must be minutes (a whole number) or SLURM time text such as \"02:00:00\", got {value}")
    if isinstance(value, int) and value >= 1:
        return value
    if isinstance(value, str) and re.fullmatch(r"(\d+-)?\d+(:\d{1,2}){0,2}", value.strip()):
        return value.strip()
    raise Invalid("{name} must be minutes (a whole number >= 1) or SLURM time text such as \"02:00:00\" or "
                  "\"1-00:00:00\", got {value}")


def _memory(value: Any) -> Any:
    """GB (a number) or SLURM text with a unit (``"500M"``, ``"16G"``)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0 and math.isfinite(value):
        return value
    if isinstance(value, str) and re.fullmatch(r"\d+(\.\d+)?[KMGT]B?", value.strip(), re.I):
        return value.strip().upper()
    raise Invalid("{name} must be GB (a number > 0) or SLURM text such as \"500M\" or \"16G\", got {value}")


RESOURCES = (
    text("partition", None, "SLURM partition (-p)", nullable=True),
    anything("time", None, "time limit per task: minutes, or \"HH:MM:SS\" / \"D-HH:MM:SS\"", check=_time,
             type_label="int | str"),
    whole("cpus", 1, "CPUs per task (also the task's BLAS/torch threads)", low=1),
    anything("memory", None, "memory per task: GB, or \"500M\" / \"16G\"", check=_memory, type_label="float | str"),
    whole("gpus", 0, "GPUs per task", low=0),
    text("account", None, "SLURM account (-A)", nullable=True),
    text("qos", None, "SLURM quality of service", nullable=True),
    text("constraint", None, "SLURM node features (-C)", nullable=True),
)
"""What one method's tasks ask for (the top of [slurm], and each [slurm.methods.NAME])."""
METHOD = Declaration(*RESOURCES)
SLURM = Declaration(
    *RESOURCES,
    whole("max_parallel", 32, "tasks of one array running at once (SLURM's --array=...%N)", low=1),
    listing("setup", [], "shell lines each task runs first (module load ..., source venv/bin/activate)",
            items="str", min_items=0),
    choice("cluster", "slurm", "slurm; local: tasks as processes of this machine (submitit's local executor, "
           "for tests and a dry run); debug: in this process", CLUSTERS),
    anything("methods", {}, "[slurm.methods.NAME] tables: one method's resources, over the defaults above",
             type_label="table"),
)
"""The experiment's ``[slurm]`` table (``--slurm KEY=VALUE`` overrides its top-level keys)."""


def check_slurm(raw: Any, methods: Iterable[str], origin: str) -> dict[str, Any]:
    """The ``[slurm]`` table as given (not filled in), checked: its keys, each value, and that each
    ``[slurm.methods.NAME]`` names a method of the experiment (one SpecError otherwise)."""
    if not raw:
        return {}
    if not isinstance(raw, Mapping):
        raise SpecError(f"{origin}: 'slurm' must be a table such as [slurm] partition = \"cpu\", got {raw!r}")
    checked = SLURM.validate(dict(raw), f"{origin}: [slurm]", SpecError, name="{key}", fill=False,
                             unknown_noun="key(s)", known_label="allowed")
    per = raw.get("methods", {}) or {}
    if not isinstance(per, Mapping) or not all(isinstance(v, Mapping) for v in per.values()):
        raise SpecError(f"{origin}: [slurm.methods.NAME] entries must be tables of resources, got {per!r}")
    stray = sorted(set(per) - set(methods))
    if stray:
        raise SpecError(f"{origin}: [slurm.methods] gives resources for method(s) not run: {', '.join(stray)}")
    checked["methods"] = {name: METHOD.validate(dict(v), f"{origin}: [slurm.methods.{name}]", SpecError,
                                                name="{key}", fill=False, unknown_noun="key(s)", known_label="allowed")
                          for name, v in per.items()}
    if not checked["methods"]:
        del checked["methods"]
    return checked


def parse_slurm_options(texts: Iterable[str]) -> dict[str, Any]:
    """``--slurm KEY=VALUE`` texts as a table of top-level [slurm] keys (numbers as numbers), checked."""
    out: dict[str, Any] = {}
    for item in texts:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise SpecError(f"--slurm {item!r}: give KEY=VALUE, e.g. --slurm partition=cpu or --slurm time=120")
        if key == "methods":
            raise SpecError("--slurm methods=...: per-method resources go in the experiment's [slurm.methods.NAME] "
                            "tables")
        value = value.strip()
        if key == "setup":
            out.setdefault("setup", []).append(value)
        elif re.fullmatch(r"\d+", value):
            out[key] = int(value)
        elif re.fullmatch(r"\d*\.\d+", value):
            out[key] = float(value)
        else:
            out[key] = value
    return check_slurm(out, (), "--slurm") if out else {}


def resources(settings: Mapping[str, Any], method: str) -> dict[str, Any]:
    """One method's resources: the defaults, the top of [slurm], then its [slurm.methods.NAME]."""
    base = {f.name: f.default for f in RESOURCES}
    base.update({k: v for k, v in settings.items() if k in base})
    base.update((settings.get("methods") or {}).get(method, {}))
    return base
