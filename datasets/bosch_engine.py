"""Built-in importers of a real gasoline engine's test-bench campaigns (Bosch Research, gengine1 and gengine2).

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

gengine1 (``bosch-gengine1``) is the same engine's other campaign, read the same way: thirteen
fields, inputs as above plus ``fuel_cutoff``, outputs ``pn``, ``co``, ``co2``, ``hc``, ``nox``,
``o2``, ``t_manifold``, ``t_cat``; train = measurements 10-19 and 30-39, test = 53-65. A
file of the folder outside a campaign's split is left out with a note.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from enginebench.datasets.catalog import Builtin
from enginebench.datasets.dataset import Dataset
from enginebench.datasets.import_spec import spec_from_dict
from enginebench.datasets.importer import import_spec
from enginebench.errors import DataError

FILE_PATTERN = re.compile(r"raw_(\d+)_measurement_\d+\.csv")
DT = 0.1


@dataclass(frozen=True)
class Campaign:
    """One of the publisher's campaigns: its files' fields in order and its split by measurement number."""

    name: str
    key: str                                  # the publisher's folder and dataset name (gengine1, gengine2)
    fields: tuple[tuple[str, str], ...]
    train: frozenset[int]
    test: frozenset[int]
    published: str                            # the split as the publisher states it
    split_short: str                          # the same in a catalog line
    inputs_text: str
    outputs_text: str

    @property
    def licence(self) -> str:
        return f"CC BY-SA 4.0 (attribute Bosch Research, Bosch-Engine-Datasets, {self.key}; share derivatives alike)"

    def meta(self) -> dict[str, Any]:
        return {
            "description": f"A real gasoline engine on a test bench (Bosch Research, {self.key}): transient "
                           f"measurements at 10 Hz; inputs {self.inputs_text}; outputs {self.outputs_text}, each "
                           "standardised by the publisher.",
            "provenance": f"Bosch Research, Bosch-Engine-Datasets, {self.key} "
                          "(github.com/boschresearch/Bosch-Engine-Datasets); contacts B. Rakitsch, C.-Y. Li",
            "citation": f"Bosch Research, \"Bosch-Engine-Datasets\" ({self.key}), GitHub repository, commit 16d1bae",
            "protocol": f"{self.published} (the publisher's split); outputs are simulated from the inputs alone",
            "synthetic": False,
        }


GENGINE2 = Campaign(
    name="bosch-gengine2", key="gengine2",
    fields=(("speed", "input"), ("load", "input"), ("lambda", "input"), ("ignition", "input"),
            ("pn", "output"), ("hc", "output"), ("nox", "output"), ("t_manifold", "output"), ("t_cat", "output")),
    train=frozenset(range(0, 16)), test=frozenset(range(16, 22)),
    published="train on measurements 0-15, test on 16-21", split_short="0-15 train, 16-21 test",
    inputs_text="speed, load, lambda, ignition angle",
    outputs_text="particle number, HC, NOx, exhaust-manifold and catalyst temperatures",
)
"""gengine2's nine fields in order (the publisher's Speed, Load, Lambda, Ignition Angle, Particle Numbers, HC,
NOx, Temperature exhaust manifold, Temperature catalyst 1), all standardised; measurements 0-15 train, 16-21 test."""
GENGINE1 = Campaign(
    name="bosch-gengine1", key="gengine1",
    fields=(("speed", "input"), ("load", "input"), ("lambda", "input"), ("ignition", "input"),
            ("fuel_cutoff", "input"), ("pn", "output"), ("co", "output"), ("co2", "output"), ("hc", "output"),
            ("nox", "output"), ("o2", "output"), ("t_manifold", "output"), ("t_cat", "output")),
    train=frozenset([*range(10, 20), *range(30, 40)]), test=frozenset(range(53, 66)),
    published="train on measurements 10-19 and 30-39, test on 53-65",
    split_short="10-19 and 30-39 train, 53-65 test",
    inputs_text="speed, load, lambda, ignition angle, fuel cutoff",
    outputs_text="particle number, CO, CO2, HC, NOx, O2, exhaust-manifold and catalyst temperatures",
)
"""gengine1's thirteen fields in order (Speed, Load, Lambda, Ignition Angle, Fuel Cutoff, Particle Numbers, CO,
CO2, HC, NOx, O2, Temperature exhaust manifold, Temperature catalyst 1), all standardised; measurements 10-19
and 30-39 train, 53-65 test."""
NAME = GENGINE2.name
FIELDS = GENGINE2.fields


def record_name(number: int) -> str:
    """A measurement's record name: ``m01`` for raw_000001_..."""
    return f"m{number:02d}"


def measurement_files(directory: Path) -> dict[int, Path]:
    """The folder's measurement files by measurement number."""
    found = {int(m.group(1)): p for p in sorted(directory.iterdir())
             if (m := FILE_PATTERN.fullmatch(p.name)) is not None}
    return dict(sorted(found.items()))


def import_campaign(campaign: Campaign, directory: str | Path) -> Dataset:
    """The measurements of ``directory`` (the folder holding raw_0000NN_measurement_000000.csv) that lie in the
    campaign's published split; a file outside it is left out with a note."""
    directory = Path(directory)
    if not directory.is_dir():
        raise DataError(f"{directory}: not a folder; pass the folder holding raw_0000NN_measurement_000000.csv "
                        "to --from")
    found = measurement_files(directory)
    files = {n: p for n, p in found.items() if n in campaign.train or n in campaign.test}
    train = [record_name(n) for n in files if n in campaign.train]
    test = [record_name(n) for n in files if n in campaign.test]
    if not train or not test:
        have = ", ".join(p.name for p in found.values()) or "no raw_*_measurement_*.csv file"
        raise DataError(
            f"{directory}: the {campaign.name} import needs measurements of both sides of the publisher's split "
            f"({campaign.published}); found {have}"
        )
    doc = {
        "name": campaign.name,
        "dt": DT,
        "header": False,
        "licence": campaign.licence,
        "provenance": campaign.meta()["provenance"],
        "columns": {name: {"role": role, "unit": "1"} for name, role in campaign.fields},
        "records": {record_name(n): {"file": p.name} for n, p in files.items()},
    }
    ds = import_spec(spec_from_dict(doc, directory / f"[built-in {campaign.name} import]"))
    meta = {k: v for k, v in campaign.meta().items() if k != "provenance"}
    meta["published_split"] = {"train": train, "test": test}
    meta["measurements"] = {record_name(n): p.name for n, p in files.items()}
    outside = sorted(set(found) - set(files))
    if outside:
        meta["notes"] = [*ds.meta.get("notes", []), f"{len(outside)} file(s) outside the publisher's split left out: "
                         + ", ".join(found[n].name for n in outside)]
    return ds.with_frame(ds.frame, **meta)


def import_gengine2(directory: str | Path) -> Dataset:
    """gengine2's measurements in ``directory``."""
    return import_campaign(GENGINE2, directory)


def import_gengine1(directory: str | Path) -> Dataset:
    """gengine1's measurements in ``directory``."""
    return import_campaign(GENGINE1, directory)


def _builtin(campaign: Campaign, importer: Any) -> Builtin:
    """A campaign's catalog entry, described from its fields and split."""
    names = {role: ", ".join(n for n, r in campaign.fields if r == role) for role in ("input", "output")}
    return Builtin(
        name=campaign.name,
        kind="real",
        description=f"A real gasoline engine on a test bench (Bosch Research, {campaign.key}): transient measurements "
                    f"at 10 Hz, inputs {names['input']}; outputs {names['output']} (all standardised); published "
                    f"split by measurement ({campaign.split_short})",
        licence="CC BY-SA 4.0",
        importer=importer,
        targets=tuple(n for n, role in campaign.fields if role == "output"),
        notes={"import": f"enginebench datasets import {campaign.name} --from DIR (the folder with the headerless "
                         "raw_0000NN_measurement_000000.csv files)"},
        order=3,
    )


DATASETS = (_builtin(GENGINE2, import_gengine2), _builtin(GENGINE1, import_gengine1))
"""The catalog's entries (``datasets/catalog.py`` finds them here)."""
