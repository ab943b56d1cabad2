"""Built-in importers of two published nonlinear system-identification records.

Both read the files exactly as the nonlinear system identification benchmarks collection
distributes them (no time column, a trailing comma on every line, F-16: the sampling rate
once in the first row), through the same import-spec machinery a user's TOML spec goes
through (:func:`enginebench.datasets.import_spec.spec_from_dict`): a built-in is a spec
written in code, so it gets the same checks, notes and messages.

- ``silverbox``: one record ``SNLS80mV`` (131,072 samples), input ``V1`` and output
  ``V2`` in volts, dt = 2^14 / 10^7 s = 1.6384 ms exactly (a sampling frequency of
  10^7 / 2^14 = 610.3515625 Hz, the benchmark's "610.35 Hz").
- ``f16-gvt``: four records named after the file stems, input ``Force`` (N), outputs
  ``Acceleration1``-``3`` (m/s^2), dt = 1/400 s, checked against the files' ``Fs``
  column. ``Voltage`` (the shaker's drive voltage, V) is role ``internal``: it is an
  alternative excitation signal, not a second input of the customary protocol (which
  drives the model with the measured force); an experiment may use it instead with
  ``roles = { Voltage = "input", Force = "internal" }``.

Column names are the files' own, so experiments name them as the literature does.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from enginebench.datasets.catalog import Builtin
from enginebench.datasets.dataset import Dataset
from enginebench.datasets.import_spec import spec_from_dict
from enginebench.datasets.importer import import_spec
from enginebench.errors import DataError

COLLECTION = "the nonlinear system identification benchmarks collection (nonlinearbenchmark.org)"
LICENCE = "none stated by the distributor (a free download for research); cite the paper under citation"

SILVERBOX_FS = 1e7 / 2**14
"""The Silverbox sampling frequency in Hz: 610.3515625 (dt = 1.6384 ms)."""
SILVERBOX_FILE = "SNLS80mV.csv"
SILVERBOX_META: dict[str, Any] = {
    "description": "Silverbox: an electronic circuit that behaves as a mass-spring-damper with a cubic "
                   "(hardening) spring, excited by a voltage V1; the response is the voltage V2.",
    "provenance": f"T. Wigren and J. Schoukens, record SNLS80mV of {COLLECTION}",
    "citation": "T. Wigren, J. Schoukens, \"Three free data sets for development and benchmarking in nonlinear "
                "system identification\", European Control Conference (ECC), Zurich, 2013",
    "protocol": "samples 0 to about 40,000 (the 'arrow', an excitation whose amplitude grows) are the customary "
                "test part; the multisine realisations that follow are for estimation",
    "synthetic": False,
}

F16_FILES = (
    "F16Data_FullMSine_Level1.csv",
    "F16Data_FullMSine_Level2_Validation.csv",
    "F16Data_FullMSine_Level3.csv",
    "F16Data_FullMSine_Level4_Validation.csv",
)
F16_RATE_HZ = 400.0
F16_META: dict[str, Any] = {
    "description": "F-16 ground vibration test: a full-scale F-16 on the ground, shaken under the right wing "
                   "with multisines at four levels; nonlinear through the wing-to-payload mounting interfaces.",
    "provenance": f"J.P. Noel and M. Schoukens, F-16 full multisine records of {COLLECTION}",
    "citation": "J.P. Noel, M. Schoukens, \"F-16 aircraft benchmark based on ground vibration test data\", "
                "Workshop on Nonlinear System Identification Benchmarks, 2017",
    "protocol": "estimate on the odd levels (1, 3), validate on the even _Validation levels (2, 4); the score is "
                "the simulation error of the accelerations",
    "published_split": {
        "train": [Path(F16_FILES[0]).stem, Path(F16_FILES[2]).stem],
        "test": [Path(F16_FILES[1]).stem, Path(F16_FILES[3]).stem],
    },
    "synthetic": False,
}


def _check_folder(directory: Path, files: tuple[str, ...], name: str) -> None:
    if not directory.is_dir():
        raise DataError(f"{directory}: not a folder; pass the folder holding {', '.join(files)} to --from")
    missing = [f for f in files if not (directory / f).is_file()]
    if missing:
        raise DataError(
            f"{directory / missing[0]}: file not found; the {name} import needs {', '.join(files)} in the "
            "folder given to --from (as the benchmark collection distributes them)"
        )


def _import(directory: Path, name: str, doc: dict[str, Any], meta: dict[str, Any]) -> Dataset:
    spec = spec_from_dict({"name": name, "licence": LICENCE, "provenance": meta["provenance"], **doc},
                          directory / f"[built-in {name} import]")
    ds = import_spec(spec)
    return ds.with_frame(ds.frame, **{k: v for k, v in meta.items() if k != "provenance"})


def import_silverbox(directory: str | Path) -> Dataset:
    """The Silverbox record ``SNLS80mV`` from ``directory`` (the folder holding SNLS80mV.csv)."""
    directory = Path(directory)
    _check_folder(directory, (SILVERBOX_FILE,), "silverbox")
    doc = {
        "files": [SILVERBOX_FILE],
        "dt": 1.0 / SILVERBOX_FS,
        "columns": {"V1": {"role": "input", "unit": "V"}, "V2": {"role": "output", "unit": "V"}},
    }
    return _import(directory, "silverbox", doc, SILVERBOX_META)


def import_f16(directory: str | Path) -> Dataset:
    """The four F-16 ground vibration test records from ``directory``."""
    directory = Path(directory)
    _check_folder(directory, F16_FILES, "f16-gvt")
    doc = {
        "files": list(F16_FILES),
        "dt": 1.0 / F16_RATE_HZ,
        "rate_column": "Fs",
        "columns": {
            "Force": {"role": "input", "unit": "N"},
            "Voltage": {"role": "internal", "unit": "V"},
            "Acceleration1": {"role": "output", "unit": "m/s^2"},
            "Acceleration2": {"role": "output", "unit": "m/s^2"},
            "Acceleration3": {"role": "output", "unit": "m/s^2"},
        },
    }
    return _import(directory, "f16-gvt", doc, F16_META)


DATASETS = (
    Builtin(
        name="silverbox",
        kind="real",
        description="Silverbox (Wigren & Schoukens 2013): electronic nonlinear mass-spring-damper, one record "
                    "SNLS80mV of 131,072 samples at 610.3515625 Hz; input V1, output V2 (V)",
        licence="none stated by the distributor; cite Wigren & Schoukens, ECC 2013",
        importer=import_silverbox,
        targets=("V2",),
        notes={"import": "enginebench datasets import silverbox --from DIR (the folder with SNLS80mV.csv)"},
        order=1,
    ),
    Builtin(
        name="f16-gvt",
        kind="real",
        description="F-16 ground vibration test (Noel & Schoukens 2017): 4 multisine records of 73,728 samples "
                    "at 400 Hz; input Force (N), outputs Acceleration1-3 (m/s^2); Voltage internal",
        licence="none stated by the distributor; cite Noel & Schoukens, 2017",
        importer=import_f16,
        targets=("Acceleration1", "Acceleration2", "Acceleration3"),
        notes={"import": "enginebench datasets import f16-gvt --from DIR (the folder with the four "
                         "F16Data_FullMSine_*.csv files)"},
        order=2,
    ),
)
"""The catalog's entries (``datasets/catalog.py`` finds them here)."""
