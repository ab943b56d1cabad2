"""Built-in datasets and where datasets live on disk.

Imported and generated datasets are cached as Parquet files in the data home:
``$ENGINEBENCH_DATA`` if set, else ``~/.cache/enginebench/datasets``. An experiment names
a dataset by its built-in name, by a ``.parquet`` file, or by a ``.toml`` import spec.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
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


def _gas_turbine_import(directory: Path) -> Dataset:
    from enginebench.datasets.gas_turbine.importer import import_directory

    return import_directory(directory)


BUILTINS: dict[str, Builtin] = {
    "gas-turbine-emissions": Builtin(
        name="gas-turbine-emissions",
        kind="real",
        description="36,733 hourly records 2011-2015 of an industrial gas turbine (UCI); targets NOX, CO, TAT; "
                    "published split 2011-2013 / 2014-2015",
        licence="CC BY 4.0",
        importer=_gas_turbine_import,
        targets=("NOX", "CO", "TAT"),
        notes={"import": "enginebench datasets import gas-turbine-emissions --from DIR (the folder with gt_2011.csv ... gt_2015.csv)"},
    ),
}


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
    if name not in BUILTINS:
        raise DataError(f"unknown dataset {name!r}; built-ins: {', '.join(BUILTINS)} (or give a .parquet file or a .toml import spec)")
    return BUILTINS[name]


def load(ref: str | Path, *, variant: str = "", columns: list[str] | None = None) -> Dataset:
    """Load a dataset by built-in name, Parquet file or TOML import spec."""
    from enginebench.datasets.io import read_dataset

    path = Path(ref)
    if path.suffix == ".parquet":
        if not path.is_file():
            raise DataError(f"{path}: dataset file not found")
        return read_dataset(path, columns=columns)
    if path.suffix == ".toml":
        from enginebench.datasets.importer import import_table

        return import_table(path)
    builtin = get_builtin(str(ref))
    cached = cached_path(builtin.name, variant)
    if cached.is_file():
        return read_dataset(cached, columns=columns)
    if builtin.importer is not None:
        raise DataError(
            f"dataset {builtin.name!r} is not imported yet (looked in {cached}); run: {builtin.notes.get('import', 'enginebench datasets import ' + builtin.name + ' --from DIR')}"
        )
    raise DataError(f"dataset {builtin.name!r} is not generated yet; run: enginebench datasets generate {builtin.name}")
