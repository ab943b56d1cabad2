"""Experiment specs: a TOML file (or a built-in name) resolved into a complete, hashable config.

Format (every key but ``dataset``, ``targets`` and ``methods`` has a default)::

    name = "gas-turbine-nox"
    dataset = "gas-turbine-emissions"   # built-in name, .parquet file or .toml import spec
    targets = ["NOX"]
    mode = "static"                     # static | window | simulation
    windows = [0]                       # Delta in seconds (window mode)
    methods = ["naive-mean", "krls"]
    repetitions = 30
    seed = 0
    train_size = 1000                   # training subsample per repetition; 0 = all rows
    interval = "t"                      # t | bootstrap (percentile)
    roles = { TAT = "input" }           # change column roles for this experiment
    init_samples = 0                    # simulation mode: samples that set each evaluated segment's state

    [split]                             # kind = published | holdout | rolling | groups | records
    kind = "published"

    [selection]                         # kind = bootstrap | kfold | validation | none
    kind = "bootstrap"
    resamples = 5
    folds = 5
    criterion = "mae"                   # mae | rmae | rmse
    refit = true                        # refit the chosen point on training + validation rows

    [methods.krls]                      # constructor options of a method
    gamma_grid = [-4, 4, 41]
"""

from __future__ import annotations

import difflib
import hashlib
import json
import tomllib
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

from enginebench.datasets.samples import MODES
from enginebench.errors import SpecError

SELECTION_KINDS = ("bootstrap", "kfold", "validation", "none")
CRITERIA = ("mae", "rmae", "rmse")
INTERVALS = ("t", "bootstrap")

TOP_KEYS = {
    "name", "description", "dataset", "dataset_variant", "targets", "mode", "windows", "methods", "repetitions",
    "seed", "train_size", "interval", "roles", "split", "selection", "method_options", "init_samples",
}
SELECTION_KEYS = ("kind", "resamples", "folds", "criterion", "refit")

SPLIT_OPTIONS: dict[str, dict[str, tuple[type | tuple[type, ...], str]]] = {
    "published": {},
    "holdout": {"test_fraction": (float, "a fraction in (0, 1)"), "validation_fraction": (float, "a fraction in [0, 1)")},
    "rolling": {"folds": (int, "a whole number >= 1"), "test_fraction": (float, "a fraction in (0, 1)")},
    "groups": {"column": (str, "a group column's name"), "test": (list, "a list of group values"),
               "validation": (list, "a list of group values")},
    "records": {"train": (list, 'a list of record names, e.g. ["est"] or ["rec[1000:]"]'),
                "test": (list, "a list of record names"), "validation": (list, "a list of record names")},
}
"""Each split kind's options: name -> (type, what it must be). ``kind`` itself is always allowed."""
SPLIT_REQUIRED = {"groups": ("column", "test"), "records": ("train", "test")}

DEFAULT_ONLY_IN_HASH = {"init_samples": 0}
"""Keys added after runs were published: left out of ``to_dict`` (so of the config hash) at their default."""


@dataclass(frozen=True)
class Selection:
    kind: str = "bootstrap"
    resamples: int = 5
    folds: int = 5
    criterion: str = "mae"
    refit: bool = True
    """After selection, fit the chosen point on the training rows plus the validation part (kind 'validation')."""


@dataclass(frozen=True)
class ExperimentSpec:
    """A fully resolved experiment: what to run, on what, and how to evaluate it."""

    name: str
    dataset: str
    targets: tuple[str, ...]
    methods: tuple[str, ...]
    mode: str = "static"
    windows: tuple[float, ...] = (0.0,)
    repetitions: int = 30
    seed: int = 0
    train_size: int = 1000
    interval: str = "t"
    roles: dict[str, str] = field(default_factory=dict)
    split: dict[str, Any] = field(default_factory=lambda: {"kind": "published"})
    selection: Selection = Selection()
    method_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    description: str = ""
    dataset_variant: str = ""
    init_samples: int = 0

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["targets"], d["methods"], d["windows"] = list(self.targets), list(self.methods), list(self.windows)
        for key, default in DEFAULT_ONLY_IN_HASH.items():
            if d[key] == default:
                del d[key]
        if d["selection"]["refit"] is True:  # the default: earlier runs' configs (and hashes) stay as they were
            del d["selection"]["refit"]
        return d

    def config_hash(self) -> str:
        """Hash of everything that determines the results (the name and description excluded)."""
        d = self.to_dict()
        d.pop("name"), d.pop("description")
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()

    def with_overrides(self, **changes: Any) -> "ExperimentSpec":
        d = self.to_dict()
        d.update({k: v for k, v in changes.items() if v is not None})
        d["selection"] = d["selection"] if isinstance(d["selection"], dict) else asdict(d["selection"])
        return from_dict(d, origin="command-line overrides")


def _expect(cond: bool, origin: str, message: str) -> None:
    if not cond:
        raise SpecError(f"{origin}: {message}")


def _is(value: Any, kind: type | tuple[type, ...]) -> bool:
    """Strict type test: a boolean is never a number, an integer is a float."""
    if isinstance(value, bool):
        return kind is bool or (isinstance(kind, tuple) and bool in kind)
    if kind is float:
        return isinstance(value, (int, float))
    return isinstance(value, kind)


def _unknown_keys(unknown: set[str], allowed: Sequence[str]) -> str:
    """'unknown key(s) a (did you mean 'b'?); allowed: ...' for a spec table."""
    parts = []
    for key in sorted(unknown):
        close = difflib.get_close_matches(key, list(allowed), n=1)
        parts.append(key + (f" (did you mean {close[0]!r}?)" if close else ""))
    return f"unknown key(s) {', '.join(parts)}; allowed: {', '.join(sorted(allowed))}"


def check_split(raw: Any, origin: str) -> dict[str, Any]:
    """The ``[split]`` table, its keys and their types checked for its kind (one SpecError otherwise)."""
    if isinstance(raw, str):  # split = "holdout" as a plain string: the kind alone
        raw = {"kind": raw}
    _expect(isinstance(raw, dict), origin, f"'split' must be a table such as [split] kind = \"holdout\", got {raw!r}")
    split = dict(raw)
    split.setdefault("kind", "published")
    kind = split["kind"]
    _expect(isinstance(kind, str) and kind in SPLIT_OPTIONS, origin,
            f"split kind {kind!r} is not one of {', '.join(SPLIT_OPTIONS)}")
    options = SPLIT_OPTIONS[kind]
    unknown = set(split) - set(options) - {"kind"}
    _expect(not unknown, origin, f"[split] kind = {kind!r}: " + _unknown_keys(unknown, [*options, "kind"]))
    for key in SPLIT_REQUIRED.get(kind, ()):
        _expect(key in split, origin, f"[split] kind = {kind!r} needs {key!r} ({options[key][1]})")
    for key, (kind_type, what) in options.items():
        if key in split:
            value = split[key]
            _expect(_is(value, kind_type), origin, f"[split] {key} must be {what}, got {value!r}")
            if kind_type is list and kind == "records":
                _expect(all(isinstance(v, str) and v.strip() for v in value), origin,
                        f"[split] {key} must be a list of record names (strings), got {value!r}")
    return split


def from_dict(raw: dict[str, Any], origin: str = "spec", base_dir: Path | None = None) -> ExperimentSpec:
    """Validate a spec dict (from TOML) and fill in defaults."""
    raw = dict(raw)
    if "methods" in raw and isinstance(raw["methods"], dict):
        # [methods.NAME] tables give options; the method list then comes from 'run' or the table keys
        options = raw.pop("methods")
        raw.setdefault("method_options", {}).update(options)
        raw["methods"] = raw.pop("run", list(options))
    unknown = set(raw) - TOP_KEYS - {"run"}
    _expect(not unknown, origin, _unknown_keys(unknown, sorted(TOP_KEYS)))
    for key in ("dataset", "targets", "methods"):
        _expect(key in raw, origin, f"missing required key {key!r}")
    name = str(raw.get("name", Path(origin).stem))
    dataset = raw["dataset"]
    _expect(isinstance(dataset, str) and dataset, origin, "'dataset' must be a dataset name or a file path")
    if base_dir is not None and Path(dataset).suffix in (".parquet", ".toml") and not Path(dataset).is_absolute():
        dataset = str((base_dir / dataset).resolve())
    targets = raw["targets"]
    targets = [targets] if isinstance(targets, str) else targets
    _expect(isinstance(targets, list) and targets and all(isinstance(t, str) for t in targets), origin,
            "'targets' must be a non-empty list of column names")
    twice = sorted({t for t in targets if targets.count(t) > 1})
    _expect(not twice, origin, f"'targets' lists {', '.join(map(repr, twice))} more than once")
    methods = raw["methods"]
    methods = [methods] if isinstance(methods, str) else methods
    _expect(isinstance(methods, list) and methods and all(isinstance(m, str) for m in methods), origin,
            "'methods' must be a non-empty list of method names")
    _expect(len(set(methods)) == len(methods), origin, "'methods' lists a method twice")
    mode = raw.get("mode", "static")
    _expect(mode in MODES, origin, f"mode {mode!r} is not one of {', '.join(MODES)}")
    windows = raw.get("windows", [0])
    windows = [windows] if _is(windows, float) else windows
    _expect(isinstance(windows, list) and windows and all(_is(w, float) and w >= 0 for w in windows),
            origin, "'windows' must be a list of non-negative numbers of seconds")
    _expect(mode == "window" or all(w == 0 for w in windows), origin, f"windows > 0 need mode = 'window' (mode is {mode!r})")
    reps = raw.get("repetitions", 30)
    _expect(_is(reps, int) and reps >= 1, origin, f"'repetitions' must be an integer >= 1, got {reps!r}")
    seed = raw.get("seed", 0)
    _expect(_is(seed, int) and seed >= 0, origin, f"'seed' must be a non-negative integer, got {seed!r}")
    train_size = raw.get("train_size", 1000)
    _expect(_is(train_size, int) and train_size >= 0, origin, f"'train_size' must be an integer >= 0, got {train_size!r}")
    init_samples = raw.get("init_samples", 0)
    _expect(_is(init_samples, int) and init_samples >= 0, origin,
            f"'init_samples' must be a whole number of samples >= 0, got {init_samples!r}")
    _expect(mode == "simulation" or init_samples == 0, origin,
            f"init_samples = {init_samples} needs mode = 'simulation' (mode is {mode!r})")
    interval = raw.get("interval", "t")
    _expect(interval in INTERVALS, origin, f"interval {interval!r} is not one of {', '.join(INTERVALS)}")
    roles = raw.get("roles", {})
    _expect(isinstance(roles, dict) and all(isinstance(v, str) for v in roles.values()), origin,
            "'roles' must be a table of column = role")
    split = check_split(raw.get("split", {"kind": "published"}), origin)
    sel_raw = raw.get("selection", {})
    _expect(isinstance(sel_raw, dict), origin, "'selection' must be a table")
    unknown = set(sel_raw) - set(SELECTION_KEYS)
    _expect(not unknown, origin, "[selection]: " + _unknown_keys(unknown, SELECTION_KEYS))
    selection = Selection(**sel_raw)
    _expect(isinstance(selection.kind, str) and selection.kind in SELECTION_KINDS, origin,
            f"selection kind {selection.kind!r} is not one of {', '.join(SELECTION_KINDS)}")
    _expect(isinstance(selection.criterion, str) and selection.criterion in CRITERIA, origin,
            f"selection criterion {selection.criterion!r} is not one of {', '.join(CRITERIA)}")
    _expect(_is(selection.resamples, int) and selection.resamples >= 1, origin, "selection resamples must be an integer >= 1")
    _expect(_is(selection.folds, int) and selection.folds >= 2, origin, "selection folds must be an integer >= 2")
    _expect(isinstance(selection.refit, bool), origin, f"selection refit must be true or false, got {selection.refit!r}")
    method_options = raw.get("method_options", {})
    _expect(isinstance(method_options, dict) and all(isinstance(v, dict) for v in method_options.values()),
            origin, "[methods.NAME] entries must be tables of options")
    stray = set(method_options) - set(methods)
    _expect(not stray, origin, f"options given for method(s) not run: {', '.join(sorted(stray))}")
    return ExperimentSpec(
        name=name, dataset=dataset, targets=tuple(targets), methods=tuple(methods), mode=mode,
        windows=tuple(float(w) for w in windows), repetitions=reps, seed=seed, train_size=train_size,
        interval=interval, roles=dict(roles), split=split, selection=selection,
        method_options={k: dict(v) for k, v in method_options.items()},
        description=str(raw.get("description", "")), dataset_variant=str(raw.get("dataset_variant", "")),
        init_samples=init_samples,
    )


def builtin_names() -> list[str]:
    folder = resources.files("enginebench.experiments") / "builtin"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_spec(ref: str | Path) -> ExperimentSpec:
    """Load an experiment by built-in name or TOML path."""
    path = Path(ref)
    if path.suffix != ".toml":
        if str(ref) not in builtin_names():
            raise SpecError(f"unknown experiment {str(ref)!r}; built-ins: {', '.join(builtin_names())} (or give a .toml file)")
        text = (resources.files("enginebench.experiments") / "builtin" / f"{ref}.toml").read_text()
        origin, base = f"built-in experiment {ref}", None
    else:
        if not path.is_file():
            raise SpecError(f"{path}: experiment file not found")
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise SpecError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start}); save the experiment as UTF-8"
                            ) from None
        origin, base = str(path), path.parent
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{origin}: invalid TOML: {exc}") from None
    raw.setdefault("name", path.stem)
    return from_dict(raw, origin=origin, base_dir=base)
