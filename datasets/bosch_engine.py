"""Built-in importer of a real gasoline engine's test-bench campaign (Bosch Research, gengine2).

The publisher's files are read as they are distributed: one transient measurement per file
``raw_0000NN_measurement_000000.csv``, **no header row**, nine fields in a fixed order, 10 Hz.
The import is a spec written in code (``header = false``, one ``[records.NAME]`` table a
file), so it goes through the same checks and messages as a user's spec.

- records ``m01``, ``m03``, ... named by the measurement number NN;
- inputs ``speed``, ``load``, ``lambda``, ``ignition`` (ignition angle); outputs ``pn``
  (particle number), ``hc``, ``nox``, ``t_manifold`` (exhaust-manifold temperature),
  ``t_cat`` (catalyst temperature 1); every column was standardised by the publisher
  (zero mean and unit variance on their training set), so the unit is ``1``;
- published split by measurement: train = measurements 0-15, test = 16-21; whichever of
  them the folder holds are imported (the copy in ``../shared/data`` has 13).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from enginebench.datasets.catalog import Builtin
from enginebench.datasets.dataset import Dataset
from enginebench.datasets.import_spec import spec_from_dict
from enginebench.datasets.importer import import_spec
from enginebench.errors import DataError

NAME = "bosch-gengine2"
FILE_PATTERN = re.compile(r"raw_(\d+)_measurement_\d+\.csv")
FIELDS = (("speed", "input"), ("load", "input"), ("lambda", "input"), ("ignition", "input"),
          ("pn", "output"), ("hc", "output"), ("nox", "output"), ("t_manifold", "output"), ("t_cat", "output"))
"""The files' nine fields in order (the publisher's Speed, Load, Lambda, Ignition Angle, Particle
Numbers, HC, NOx, Temperature exhaust manifold, Temperature catalyst 1), all standardised."""
TRAIN_LAST = 15
"""Measurements 0-15 are the publisher's training set, 16-21 the test set."""
DT = 0.1
LICENCE = "CC BY-SA 4.0 (attribute Bosch Research, Bosch-Engine-Datasets, gengine2; share derivatives alike)"
META: dict[str, Any] = {
    "description": "A real gasoline engine on a test bench (Bosch Research, gengine2): transient measurements at "
                   "10 Hz; inputs speed, load, lambda, ignition angle; outputs particle number, HC, NOx, "
                   "exhaust-manifold and catalyst temperatures, each standardised by the publisher.",
    "provenance": "Bosch Research, Bosch-Engine-Datasets, gengine2 (github.com/boschresearch/Bosch-Engine-Datasets); "
                  "contacts B. Rakitsch, C.-Y. Li",
    "citation": "Bosch Research, \"Bosch-Engine-Datasets\" (gengine2), GitHub repository, commit 16d1bae",
    "protocol": "train on measurements 0-15, test on 16-21 (the publisher's split); outputs are simulated from "
                "the inputs alone",
    "synthetic": False,
}


def record_name(number: int) -> str:
    """A measurement's record name: ``m01`` for raw_000001_..."""
    return f"m{number:02d}"


def measurement_files(directory: Path) -> dict[int, Path]:
    """The folder's measurement files by measurement number."""
    found = {int(m.group(1)): p for p in sorted(directory.iterdir())
             if (m := FILE_PATTERN.fullmatch(p.name)) is not None}
    return dict(sorted(found.items()))


def import_gengine2(directory: str | Path) -> Dataset:
    """The measurements of ``directory`` (the folder holding raw_0000NN_measurement_000000.csv)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise DataError(f"{directory}: not a folder; pass the folder holding raw_0000NN_measurement_000000.csv "
                        "to --from")
    files = measurement_files(directory)
    train = [record_name(n) for n in files if n <= TRAIN_LAST]
    test = [record_name(n) for n in files if n > TRAIN_LAST]
    if not train or not test:
        have = ", ".join(p.name for p in files.values()) or "no raw_*_measurement_*.csv file"
        raise DataError(
            f"{directory}: the {NAME} import needs measurements of both sides of the publisher's split "
            f"(train 0-{TRAIN_LAST}, test {TRAIN_LAST + 1}-21); found {have}"
        )
    doc = {
        "name": NAME,
        "dt": DT,
        "header": False,
        "licence": LICENCE,
        "provenance": META["provenance"],
        "columns": {name: {"role": role, "unit": "1"} for name, role in FIELDS},
        "records": {record_name(n): {"file": p.name} for n, p in files.items()},
    }
    ds = import_spec(spec_from_dict(doc, directory / f"[built-in {NAME} import]"))
    meta = {k: v for k, v in META.items() if k != "provenance"}
    meta["published_split"] = {"train": train, "test": test}
    meta["measurements"] = {record_name(n): p.name for n, p in files.items()}
    return ds.with_frame(ds.frame, **meta)


DATASETS = (
    Builtin(
        name=NAME,
        kind="real",
        description="A real gasoline engine on a test bench (Bosch Research, gengine2): transient measurements at "
                    "10 Hz, inputs speed, load, lambda, ignition; outputs pn, hc, nox, t_manifold, t_cat (all "
                    "standardised); published split by measurement (0-15 train, 16-21 test)",
        licence="CC BY-SA 4.0",
        importer=import_gengine2,
        targets=("pn", "hc", "nox", "t_manifold", "t_cat"),
        notes={"import": "enginebench datasets import bosch-gengine2 --from DIR (the folder with the headerless "
                         "raw_0000NN_measurement_000000.csv files)"},
        order=3,
    ),
)
"""The catalog's entry (``datasets/catalog.py`` finds it here)."""
