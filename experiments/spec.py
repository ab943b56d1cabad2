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
    search = "grid"                     # grid | random | bayes (optuna: pip install enginebench[search])
    trials = 50                         # points tried by random and bayes
    extend = true                       # grid search: go past a grid's edge up to the declared bounds

    [store]
    models = false                      # true: keep each job's fitted model (docs/models.md; run --keep-models)

    [methods.krls]                      # constructor options of a method
    gamma_grid = [-4, 4, 41]
"""

from __future__ import annotations

import hashlib
import json
import tomllib
import math
from dataclasses import asdict, dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Sequence

from enginebench.declare import (Declaration, Invalid, anything, choice, did_you_mean, flag, is_number, listing, number,
                                 table, text, whole)
from enginebench.errors import SpecError
from enginebench.experiments.search import SEARCHES
from enginebench.experiments.slurm_settings import check_slurm
from enginebench.results.metrics import CRITERIA
from enginebench.samples import INIT_SAMPLES, MODES, init_samples_problem

ALL_TARGETS = "all"
"""``targets = "all"`` (a string, not a list): every column of role output. A column named "all"
is named in a list: ``targets = ["all"]``."""
SELECTION_KINDS = ("bootstrap", "kfold", "validation", "none")
INTERVALS = ("t", "bootstrap")


def _names(what: str) -> Callable[[Any], list[str]]:
    """A check: one name or a non-empty list of names, returned as a list."""

    def check(value: Any) -> list[str]:
        names = [value] if isinstance(value, str) else value
        if not (isinstance(names, list) and names and all(isinstance(t, str) for t in names)):
            raise Invalid("'{name}' must be a non-empty list of " + what)
        return names

    return check


def _windows(value: Any) -> list[float]:
    windows = [value] if is_number(value) else value
    if not (isinstance(windows, list) and windows and all(is_number(w) and w >= 0 for w in windows)):
        raise Invalid("'{name}' must be a list of non-negative numbers of seconds")
    if not all(math.isfinite(w) for w in windows):
        raise Invalid("'{name}' must be finite numbers of seconds, got {value}")
    return windows


def _record_names(value: Any) -> Any:
    if not all(isinstance(v, str) and v.strip() for v in value):
        raise Invalid("{name} must be a list of record names (strings), got {value}")
    return value


def _roles(value: Any) -> Any:
    if not all(isinstance(v, str) for v in value.values()):
        raise Invalid("'roles' must be a table of column = role")
    return value


def _store(value: Any) -> Any:
    unknown = sorted(set(value) - {"models"})
    if unknown:
        raise Invalid(f"[store] knows the key models (true/false), not {', '.join(unknown)}")
    if not isinstance(value.get("models", False), bool):
        raise Invalid("[store] models must be true or false, got {value}")
    return value


def _search(value: Any) -> str:
    if not (isinstance(value, str) and value in SEARCHES):
        hint = did_you_mean(value, SEARCHES) if isinstance(value, str) else ""
        raise Invalid("selection search {value} is not one of " + ", ".join(SEARCHES) + hint)
    return value


TOP = Declaration(
    anything("name", "", "the experiment's name (default: the spec file's stem)"),
    anything("description", "", "free text shown with the run"),
    text("dataset", None, "built-in dataset name, .parquet file or .toml import spec (relative to the spec's folder)",
         message="'dataset' must be a dataset name or a file path"),
    anything("dataset_variant", "", "a variant of the dataset (e.g. a generator size)"),
    anything("targets", None, "target column(s); \"all\" = every output column of the dataset",
             check=_names("column names"), type_label="list[str] | \"all\""),
    flag("all_targets", False, "set by targets = \"all\" (every output column); resolved when the data are read"),
    flag("joint_targets", False, "methods that model several outputs jointly (Method.joint_targets) fit one job for "
         "all targets, selecting one point on the error summed over targets, each over its standard deviation"),
    choice("mode", "static", "static (inputs at t), window (inputs over the windows), simulation (free run)", MODES,
           message="mode {value} is not one of " + ", ".join(MODES)),
    anything("windows", [0], "window lengths (mode window)", check=_windows, unit="s", type_label="list[float >= 0]"),
    anything("methods", None, "methods to run (or [methods.NAME] tables of their options)",
             check=_names("method names"), type_label="list[str]"),
    whole("repetitions", 30, "repetitions (resampled training sets) per method", low=1,
          message="'{name}' must be an integer >= 1, got {value}"),
    whole("seed", 0, "seed of every random draw of the experiment", low=0,
          message="'{name}' must be a non-negative integer, got {value}"),
    whole("train_size", 1000, "training subsample per repetition; 0 = all rows", low=0, unit="rows",
          message="'{name}' must be an integer >= 0, got {value}"),
    choice("interval", "t", "confidence intervals: Student t or bootstrap percentile", INTERVALS,
           message="interval {value} is not one of " + ", ".join(INTERVALS)),
    table("roles", {}, "column = role changes for this experiment", check=_roles,
          message="'roles' must be a table of column = role"),
    anything("split", {"kind": "published"}, "the train/test split: [split] table (kind and its keys) or a kind"),
    table("selection", {}, "model selection: [selection] table", message="'selection' must be a table"),
    table("method_options", {}, "options per method ([methods.NAME] tables)",
          message="[methods.NAME] entries must be tables of options"),
    INIT_SAMPLES,
    table("store", {}, "what a run keeps besides its metrics: [store] models = true stores each job's fitted model "
          "(docs/models.md); not part of the config hash", check=_store,
          message="'store' must be a table such as [store] models = true"),
    table("slurm", {}, "resources of --executor slurm ([slurm] and [slurm.methods.NAME], experiments/slurm_settings.py); "
          "not part of the config hash", message="'slurm' must be a table such as [slurm] partition = \"cpu\""),
)
"""The experiment spec's top-level keys (``run`` names the methods when [methods.NAME] tables are given)."""

SELECTION = Declaration(
    choice("kind", "bootstrap", "how hyperparameters are selected", SELECTION_KINDS,
           message="selection kind {value} is not one of " + ", ".join(SELECTION_KINDS)),
    whole("resamples", 5, "bootstrap resamples (kind bootstrap)", low=1),
    whole("folds", 5, "folds (kind kfold)", low=2),
    choice("criterion", "mae", "score minimised on the held-out part", CRITERIA,
           message="selection criterion {value} is not one of " + ", ".join(CRITERIA)),
    flag("refit", True, "refit the chosen point on training + validation rows"),
    anything("search", "grid", "grid (every point of the methods' grids), random (trials points drawn from the "
             "ranges the grids span) or bayes (optuna's TPE over those ranges)", check=_search,
             type_label="choice: " + " | ".join(SEARCHES)),
    whole("trials", 50, "points tried by search random or bayes", low=1,
          message="selection trials must be a whole number >= 1, got {value}"),
    flag("extend", True, "grid search: a value selected at a grid's edge is searched further, up to the bounds "
         "the method declares (false: the grids as declared, e.g. a paper's protocol)"),
)

_KIND = text("kind", "published", "split kind")
SPLITS: dict[str, Declaration] = {
    "published": Declaration(_KIND),
    "holdout": Declaration(
        _KIND,
        number("test_fraction", None, "share of the rows (or segments) tested", low=0, high=1, low_open=True,
               high_open=True, message="{name} must be a fraction in (0, 1), got {value}"),
        number("validation_fraction", None, "share of the training part held out for validation", low=0, high=1,
               high_open=True, message="{name} must be a fraction in [0, 1), got {value}"),
    ),
    "rolling": Declaration(
        _KIND,
        whole("folds", None, "rolling-origin folds", low=1, message="{name} must be a whole number >= 1, got {value}"),
        number("test_fraction", None, "share of the rows tested per fold", low=0, high=1, low_open=True,
               high_open=True, message="{name} must be a fraction in (0, 1), got {value}"),
    ),
    "groups": Declaration(
        _KIND,
        text("column", None, "the group column", message="{name} must be a group column's name, got {value}"),
        listing("test", None, "group values tested", min_items=0,
                message="{name} must be a list of group values, got {value}"),
        listing("validation", None, "group values held out for validation", min_items=0,
                message="{name} must be a list of group values, got {value}"),
    ),
    "records": Declaration(
        _KIND,
        listing("train", None, 'record names trained on, e.g. ["est"] or ["rec[1000:]"]', min_items=0,
                check=_record_names, message='{name} must be a list of record names, e.g. ["est"] or ["rec[1000:]"], '
                                         "got {value}"),
        listing("test", None, "record names tested", min_items=0, check=_record_names,
                message="{name} must be a list of record names, got {value}"),
        listing("validation", None, "record names held out for validation", min_items=0, check=_record_names,
                message="{name} must be a list of record names, got {value}"),
    ),
}
"""Each split kind's keys, selected by ``kind``."""
SPLIT_REQUIRED = {"groups": ("column", "test"), "records": ("train", "test")}


DEFAULT_ONLY_IN_HASH = {"init_samples": 0, "all_targets": False, "joint_targets": False, "slurm": {}, "store": {}}
"""Keys added after runs were published: left out of ``to_dict`` (so of the config hash) at their default."""
SELECTION_DEFAULT_ONLY_IN_HASH = {"refit": True, "search": "grid", "trials": 50, "extend": True}
"""The same for [selection] keys: earlier runs' configs (and hashes) stay as they were."""


@dataclass(frozen=True)
class Selection:
    kind: str = "bootstrap"
    resamples: int = 5
    folds: int = 5
    criterion: str = "mae"
    refit: bool = True
    """After selection, fit the chosen point on the training rows plus the validation part (kind 'validation')."""
    search: str = "grid"
    """grid | random | bayes (``experiments/search.py``)."""
    trials: int = 50
    """Points tried by random and bayes search."""
    extend: bool = True
    """Grid search goes past a grid's edge up to the method's declared bounds (``experiments/extension.py``)."""


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
    joint_targets: bool = False
    """Methods declaring ``joint_targets`` get one job per (window, split, repetition) for all targets."""
    all_targets: bool = False
    """``targets = "all"``: every output column of the dataset, resolved when the data are read
    (:meth:`with_outputs`); a stored run's config holds the resolved list."""
    slurm: dict[str, Any] = field(default_factory=dict)
    """The ``[slurm]`` table: where ``--executor slurm`` runs each method's jobs; kept in the run's config (so a
    resume asks for the same resources) but not in its config hash (it never changes a result)."""
    store: dict[str, Any] = field(default_factory=dict)
    """The ``[store]`` table: ``models = true`` keeps each job's fitted model (``experiments/keep.py``)."""

    @property
    def store_models(self) -> bool:
        """``[store] models = true``: every job stores its fitted model (``run --keep-models`` sets it)."""
        return bool(self.store.get("models", False))

    def with_outputs(self, outputs: Sequence[str]) -> "ExperimentSpec":
        """The spec with ``targets = "all"`` resolved to the dataset's output columns (unchanged otherwise)."""
        if not self.all_targets:
            return self
        if not outputs:
            raise SpecError(f"experiment {self.name!r}: targets = \"all\" but the dataset has no output column")
        return replace(self, targets=tuple(outputs), all_targets=False)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["targets"], d["methods"], d["windows"] = list(self.targets), list(self.methods), list(self.windows)
        for key, default in DEFAULT_ONLY_IN_HASH.items():
            if d[key] == default:
                del d[key]
        for key, default in SELECTION_DEFAULT_ONLY_IN_HASH.items():
            if d["selection"][key] == default and type(d["selection"][key]) is type(default):
                del d["selection"][key]
        return d

    def config_hash(self) -> str:
        """Hash of everything that determines the results (the name and description excluded)."""
        d = self.to_dict()
        d.pop("name"), d.pop("description"), d.pop("slurm", None), d.pop("store", None)
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()

    def with_overrides(self, **changes: Any) -> "ExperimentSpec":
        d = self.to_dict()
        d.update({k: v for k, v in changes.items() if v is not None})
        d["selection"] = d["selection"] if isinstance(d["selection"], dict) else asdict(d["selection"])
        return from_dict(d, origin="command-line overrides")


def _expect(cond: bool, origin: str, message: str) -> None:
    if not cond:
        raise SpecError(f"{origin}: {message}")


def check_split(raw: Any, origin: str) -> dict[str, Any]:
    """The ``[split]`` table, its keys and their types checked for its kind (one SpecError otherwise)."""
    if isinstance(raw, str):  # split = "holdout" as a plain string: the kind alone
        raw = {"kind": raw}
    _expect(isinstance(raw, dict), origin, f"'split' must be a table such as [split] kind = \"holdout\", got {raw!r}")
    split = dict(raw)
    split.setdefault("kind", "published")
    kind = split["kind"]
    _expect(isinstance(kind, str) and kind in SPLITS, origin, f"split kind {kind!r} is not one of {', '.join(SPLITS)}")
    declared = SPLITS[kind]
    problem = declared.unknown(list(split), "key(s)", "allowed")
    _expect(problem is None, origin, f"[split] kind = {kind!r}: {problem}")
    for key in SPLIT_REQUIRED.get(kind, ()):
        _expect(key in split, origin, f"[split] kind = {kind!r} needs {key!r} ({declared[key].meaning})")
    return declared.validate(split, origin, SpecError, name="[split] {key}", fill=False)


def from_dict(raw: dict[str, Any], origin: str = "spec", base_dir: Path | None = None) -> ExperimentSpec:
    """Validate a spec dict (from TOML) and fill in defaults."""
    raw = dict(raw)
    if "methods" in raw and isinstance(raw["methods"], dict):
        # [methods.NAME] tables give options; the method list then comes from 'run' or the table keys
        options = raw.pop("methods")
        raw.setdefault("method_options", {}).update(options)
        raw["methods"] = raw.pop("run", list(options))
    given = {k: v for k, v in raw.items() if k != "run"}
    problem = TOP.unknown(list(given), "key(s)", "allowed")
    _expect(problem is None, origin, str(problem))
    for key in ("dataset", "targets", "methods"):
        _expect(key in raw, origin, f"missing required key {key!r}")
    v = TOP.validate(given, origin, SpecError, name="{key}")
    name = str(raw.get("name", Path(origin).stem))
    dataset = v["dataset"]
    if base_dir is not None and Path(dataset).suffix in (".parquet", ".toml") and not Path(dataset).is_absolute():
        dataset = str((base_dir / dataset).resolve())
    targets, methods, mode, windows = v["targets"], v["methods"], v["mode"], v["windows"]
    all_targets = raw["targets"] == ALL_TARGETS or bool(raw.get("all_targets", False))
    twice = sorted({t for t in targets if targets.count(t) > 1})
    _expect(not twice, origin, f"'targets' lists {', '.join(map(repr, twice))} more than once")
    _expect(len(set(methods)) == len(methods), origin, "'methods' lists a method twice")
    twice = sorted({float(w) for w in windows if [float(x) for x in windows].count(float(w)) > 1})
    _expect(not twice, origin, f"'windows' lists {', '.join(f'{w:g}' for w in twice)} more than once")
    _expect(mode == "window" or all(w == 0 for w in windows), origin, f"windows > 0 need mode = 'window' (mode is {mode!r})")
    init_samples = v["init_samples"]
    problem = init_samples_problem(init_samples, mode)
    _expect(problem is None, origin, str(problem))
    split = check_split(v["split"], origin)
    problem = SELECTION.unknown(list(v["selection"]), "key(s)", "allowed")
    _expect(problem is None, origin, f"[selection]: {problem}")
    selection = Selection(**SELECTION.validate(v["selection"], origin, SpecError, name="selection {key}"))
    method_options = v["method_options"]
    _expect(all(isinstance(o, dict) for o in method_options.values()), origin,
            "[methods.NAME] entries must be tables of options")
    stray = set(method_options) - set(methods)
    _expect(not stray, origin, f"options given for method(s) not run: {', '.join(sorted(stray))}")
    return ExperimentSpec(
        name=name, dataset=dataset, targets=tuple(targets), methods=tuple(methods), mode=mode,
        windows=tuple(float(w) for w in windows), repetitions=v["repetitions"], seed=v["seed"],
        train_size=v["train_size"], interval=v["interval"], roles=dict(v["roles"]), split=split, selection=selection,
        method_options={k: dict(v) for k, v in method_options.items()},
        description=str(raw.get("description", "")), dataset_variant=str(raw.get("dataset_variant", "")),
        init_samples=init_samples, all_targets=all_targets, joint_targets=v["joint_targets"],
        slurm=check_slurm(v["slurm"], methods, origin), store=dict(v["store"]),
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
