"""The FMU physical model of a dataset named by its import spec or Parquet file (``enginebench calibrate pm``).

It stands on the catalog (which loads the dataset, importing the spec when it is one) and on fmu.py (the
model); fmu_calibrate.py, which fits the model, imports neither, so the import chain catalog -> importer ->
fmu -> fmu_calibrate never comes back to the catalog.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from enginebench.datasets import catalog
from enginebench.datasets.fmu import NAME, FMUPhysicalModel
from enginebench.errors import DataError


def dataset_model(ref: str, fat_datasets: Sequence[str] = ()) -> tuple[Any, Any]:
    """The FMU physical model of a dataset given by its .toml import spec or .parquet file, and the dataset."""
    if Path(ref).suffix not in (".toml", ".parquet"):
        raise DataError(f"dataset {ref!r} has no FAT-calibrated physical model; FAT calibration is available for: "
                        f"{', '.join(fat_datasets)}, and for a dataset whose import spec names an FMU (give its "
                        ".toml spec or .parquet file)")
    ds = catalog.load(ref)
    if ds.meta.get("physical_model") != NAME:
        raise DataError(f"dataset {ref!r} has no FMU physical model; name one in its import spec's "
                        "[physical_model] table (docs/data.md)")
    return FMUPhysicalModel.for_dataset(ds.meta), ds
