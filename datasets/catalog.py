"""Built-in datasets and where datasets live on disk.

A built-in is declared where its code is: a module of this package that holds a top-level
``DATASETS = (Builtin(...), ...)`` (an importer module such as ``sysid_benchmarks.py`` declares
its datasets with its import functions). :func:`builtin_datasets` finds those modules by
reading the package's source files for that line, so only they are imported, on first use
(never the generators' packages, which load scipy: their two entries are declared here with
wrappers that import on call). Adding a dataset importer is one module.

Imported and generated datasets are cached as Parquet files in the data home:
``$ENGINEBENCH_DATA`` if set, else ``~/.cache/enginebench/datasets``. An experiment names
a dataset by its built-in name, by a ``.parquet`` file, or by a ``.toml`` import spec.
"""

from __future__ import annotations

import importlib
import os
import re
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any, Callable

from enginebench.datasets.dataset import Dataset
from enginebench.errors import DataError


@dataclass(frozen=True)
class Builtin:
    """A dataset the toolkit knows by name."""

    name: str
    kind: str  # "real" or "synthetic"
    description: str
    licence: str
    importer: Callable[[Path], Dataset] | None = None   # real data: built from user-supplied files
    generator: Callable[..., Dataset] | None = None      # synthetic data: generated on demand
    targets: tuple[str, ...] = ()
    notes: dict[str, Any] = field(default_factory=dict)
    sizes: dict[str, Any] = field(default_factory=dict)  # generated data: size name -> generator argument
    default_size: str = "small"
    order: int = 100
    """Place in listings and in the 'unknown dataset' message: lower first, then real before synthetic, then name."""


def _turboshaft(size_arg: float, seed: int, progress: Callable[[float], None] | None) -> Dataset:
    from enginebench.datasets.turboshaft import generate

    return generate(hours=size_arg, seed=seed, progress=progress)


def _marine(size_arg: str, seed: int, progress: Callable[[float], None] | None) -> Dataset:
    from enginebench.datasets.marine_diesel import generate

    return generate(size=size_arg, seed=seed, progress=progress)


DATASETS = (
    Builtin(
        name="turboshaft",
        kind="synthetic",
        description="SYNTHETIC twin-engine helicopter flights at 12 Hz (13 h full, 1 h small); targets WF, TRQ; "
                    "NG, NP internal; split by flight",
        licence="CC0-1.0 (generated)",
        generator=_turboshaft,
        targets=("WF", "TRQ"),
        sizes={"small": 1.0, "full": 13.0},
        order=4,
    ),
    Builtin(
        name="marine-diesel",
        kind="synthetic",
        description="SYNTHETIC medium-speed propulsion diesel of a patrol vessel at 1/3 Hz (small: days; full: 3347 h); "
                    "targets: exhaust temperatures before/after the turbocharger",
        licence="CC0-1.0 (generated)",
        generator=_marine,
        sizes={"small": "small", "full": "full"},
        order=5,
    ),
)
"""The generated built-ins (their packages are too heavy to import for a listing); the real ones are declared
by their importer modules."""

_DECLARES = re.compile(r"^DATASETS\b[^=\n]*=", re.MULTILINE)


def _declaring_modules() -> list[str]:
    """The modules of this package whose source holds a top-level ``DATASETS = ...`` line (nothing imported)."""
    root = Path(__file__).resolve().parent
    found = []
    for path in sorted(root.rglob("*.py")):
        if _DECLARES.search(path.read_text(encoding="utf-8")):
            parts = path.relative_to(root).with_suffix("").parts
            found.append(".".join((__package__, *(parts[:-1] if parts[-1] == "__init__" else parts))))
    return found


@cache
def builtin_datasets() -> dict[str, Builtin]:
    """Every built-in dataset by name, in listing order: the ``DATASETS`` of the modules that declare them."""
    found: dict[str, tuple[Builtin, str]] = {}
    for module in _declaring_modules():
        for builtin in importlib.import_module(module).DATASETS:
            if builtin.name in found:
                raise DataError(f"built-in dataset {builtin.name!r} is declared twice: in {found[builtin.name][1]} "
                                f"and in {module}; rename one")
            found[builtin.name] = (builtin, module)
    ordered = sorted((b for b, _ in found.values()), key=lambda b: (b.order, b.kind != "real", b.name))
    return {b.name: b for b in ordered}


def variant_name(size: str, seed: int = 0) -> str:
    """Cache key of a generated dataset: its size, and the seed when not 0."""
    return size if seed == 0 else f"{size}-seed{seed}"


def generate_builtin(name: str, size: str | None = None, seed: int = 0,
                     progress: Callable[[float], None] | None = None, force: bool = False) -> Path:
    """Generate a synthetic built-in deterministically and cache it; returns the Parquet path."""
    from enginebench.datasets.io import write_dataset

    builtin = get_builtin(name)
    if builtin.generator is None:
        raise DataError(f"dataset {name!r} is real data; import it instead: {builtin.notes.get('import', '')}")
    size = size or builtin.default_size
    if size not in builtin.sizes:
        raise DataError(f"dataset {name!r} has sizes {', '.join(builtin.sizes)}, not {size!r}")
    path = cached_path(name, variant_name(size, seed))
    if path.is_file() and not force:
        return path
    ds = builtin.generator(builtin.sizes[size], seed, progress)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_dataset(ds, path)


def data_home() -> Path:
    """Folder of cached datasets (created on first write)."""
    env = os.environ.get("ENGINEBENCH_DATA")
    return Path(env) if env else Path.home() / ".cache" / "enginebench" / "datasets"


def cached_path(name: str, variant: str = "") -> Path:
    return data_home() / (f"{name}-{variant}.parquet" if variant else f"{name}.parquet")


def import_builtin(name: str, source: str | Path) -> Path:
    """Build a real built-in dataset from the user's files and cache it; returns the Parquet path."""
    from enginebench.datasets.io import write_dataset

    builtin = get_builtin(name)
    if builtin.importer is None:
        raise DataError(f"dataset {name!r} is {builtin.kind}; it is generated, not imported (use 'datasets generate')")
    ds = builtin.importer(Path(source))
    path = cached_path(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_dataset(ds, path)


def get_builtin(name: str) -> Builtin:
    builtins = builtin_datasets()
    if name not in builtins:
        raise DataError(f"unknown dataset {name!r}; built-ins: {', '.join(builtins)} (or give a .parquet file or a .toml import spec)")
    return builtins[name]


def locate(ref: str | Path, *, variant: str = "") -> Path | None:
    """The Parquet file behind a dataset reference (generating a built-in on first use); None for a TOML import spec."""
    path = Path(ref)
    if path.suffix == ".parquet":
        if not path.is_file():
            raise DataError(f"{path}: dataset file not found")
        return path
    if path.suffix == ".toml":
        return None
    builtin = get_builtin(str(ref))
    if builtin.generator is not None:
        size, _, seed = (variant or builtin.default_size).partition("-seed")
        return generate_builtin(builtin.name, size, int(seed or 0))
    cached = cached_path(builtin.name, variant)
    if cached.is_file():
        return cached
    if builtin.importer is not None:
        raise DataError(
            f"dataset {builtin.name!r} is not imported yet (looked in {cached}); run: {builtin.notes.get('import', 'enginebench datasets import ' + builtin.name + ' --from DIR')}"
        )
    raise DataError(f"dataset {builtin.name!r} is not generated yet; run: enginebench datasets generate {builtin.name}")


def load(ref: str | Path, *, variant: str = "", columns: list[str] | None = None) -> Dataset:
    """Load a dataset by built-in name, Parquet file or TOML import spec (``columns``: read only those)."""
    from enginebench.datasets.io import read_dataset

    path = locate(ref, variant=variant)
    if path is None:
        from enginebench.datasets.importer import import_table

        return import_table(Path(ref))
    return read_dataset(path, columns=columns)
