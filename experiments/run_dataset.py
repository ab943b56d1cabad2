"""What results/ needs to know about a stored run's dataset, looked up where datasets live.

results/ never imports datasets/: guard and publish take the dataset's content hash and
whether it is generated (a synthetic built-in, generated again by a reproducibility
rerun) as arguments, and the command line looks them up here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from enginebench.datasets import catalog
from enginebench.datasets.io import read_metadata
from enginebench.errors import DataError


@dataclass(frozen=True)
class RunDataset:
    """A run's dataset as guard and publish need it."""

    content_hash: str | None
    """Recorded by the run, else read from the dataset file's footer; None when neither is available."""
    generated: bool
    """True for a synthetic built-in (a rerun generates it again into its own data home)."""


def _builtin(ref: str):
    try:
        return catalog.get_builtin(ref)
    except DataError:  # a .parquet path, a .toml import spec, or an unknown name
        return None


def _footer_hash(ref: str, variant: str) -> str | None:
    builtin = None if ref.endswith(".parquet") else _builtin(ref)
    if builtin is None and not ref.endswith(".parquet"):
        return None
    try:
        path = Path(ref) if builtin is None else catalog.cached_path(
            builtin.name, variant or (builtin.default_size if builtin.generator else ""))
        return str(read_metadata(path).get("content_hash")) if path.is_file() else None
    except DataError:
        return None


def run_dataset(run) -> RunDataset:
    """The content hash and kind of ``run``'s dataset (``results.store.Run``)."""
    cfg = run.config()
    ref, variant = str(cfg.get("dataset", "")), str(cfg.get("dataset_variant", "") or "")
    builtin = _builtin(ref)
    recorded = run.info().get("dataset_hash")
    return RunDataset(str(recorded) if recorded else _footer_hash(ref, variant),
                      builtin is not None and builtin.generator is not None)
