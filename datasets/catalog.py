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
    sizes: dict[str, Any] = field(default_factory=dict)  # generated data: size name -> generator argument
    default_size: str = "small"


def _gas_turbine_import(directory: Path) -> Dataset:
    from enginebench.datasets.gas_turbine.importer import import_directory

    return import_directory(directory)


def _silverbox_import(directory: Path) -> Dataset:
    from enginebench.datasets.sysid_benchmarks import import_silverbox

    return import_silverbox(directory)


def _f16_import(directory: Path) -> Dataset:
    from enginebench.datasets.sysid_benchmarks import import_f16

    return import_f16(directory)


def _gengine2_import(directory: Path) -> Dataset:
    from enginebench.datasets.bosch_engine import import_gengine2

    return import_gengine2(directory)


def _turboshaft(size_arg: float, seed: int, progress: Callable[[float], None] | None) -> Dataset:
    from enginebench.datasets.turboshaft import generate

    return generate(hours=size_arg, seed=seed, progress=progress)


def _marine(size_arg: str, seed: int, progress: Callable[[float], None] | None) -> Dataset:
    from enginebench.datasets.marine_diesel import generate

    return generate(size=size_arg, seed=seed, progress=progress)


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
    "silverbox": Builtin(
        name="silverbox",
        kind="real",
        description="Silverbox (Wigren & Schoukens 2013): electronic nonlinear mass-spring-damper, one record "
                    "SNLS80mV of 131,072 samples at 610.3515625 Hz; input V1, output V2 (V)",
        licence="none stated by the distributor; cite Wigren & Schoukens, ECC 2013",
        importer=_silverbox_import,
        targets=("V2",),
        notes={"import": "enginebench datasets import silverbox --from DIR (the folder with SNLS80mV.csv)"},
    ),
    "f16-gvt": Builtin(
        name="f16-gvt",
        kind="real",
        description="F-16 ground vibration test (Noel & Schoukens 2017): 4 multisine records of 73,728 samples "
                    "at 400 Hz; input Force (N), outputs Acceleration1-3 (m/s^2); Voltage internal",
        licence="none stated by the distributor; cite Noel & Schoukens, 2017",
        importer=_f16_import,
        targets=("Acceleration1", "Acceleration2", "Acceleration3"),
        notes={"import": "enginebench datasets import f16-gvt --from DIR (the folder with the four "
                         "F16Data_FullMSine_*.csv files)"},
    ),
    "bosch-gengine2": Builtin(
        name="bosch-gengine2",
        kind="real",
        description="A real gasoline engine on a test bench (Bosch Research, gengine2): transient measurements at "
                    "10 Hz, inputs speed, load, lambda, ignition; outputs pn, hc, nox, t_manifold, t_cat (all "
                    "standardised); published split by measurement (0-15 train, 16-21 test)",
        licence="CC BY-SA 4.0",
        importer=_gengine2_import,
        targets=("pn", "hc", "nox", "t_manifold", "t_cat"),
        notes={"import": "enginebench datasets import bosch-gengine2 --from DIR (the folder with the headerless "
                         "raw_0000NN_measurement_000000.csv files)"},
    ),
    "turboshaft": Builtin(
        name="turboshaft",
        kind="synthetic",
        description="SYNTHETIC twin-engine helicopter flights at 12 Hz (13 h full, 1 h small); targets WF, TRQ; "
                    "NG, NP internal; split by flight",
        licence="CC0-1.0 (generated)",
        generator=_turboshaft,
        targets=("WF", "TRQ"),
        sizes={"small": 1.0, "full": 13.0},
    ),
    "marine-diesel": Builtin(
        name="marine-diesel",
        kind="synthetic",
        description="SYNTHETIC medium-speed propulsion diesel of a patrol vessel at 1/3 Hz (small: days; full: 3347 h); "
                    "targets: exhaust temperatures before/after the turbocharger",
        licence="CC0-1.0 (generated)",
        generator=_marine,
        sizes={"small": "small", "full": "full"},
    ),
}


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
    if name not in BUILTINS:
        raise DataError(f"unknown dataset {name!r}; built-ins: {', '.join(BUILTINS)} (or give a .parquet file or a .toml import spec)")
    return BUILTINS[name]


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
