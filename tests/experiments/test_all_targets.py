"""``targets = "all"``: every output column of the dataset, resolved when the data are read and stored as
the explicit list (so the run's config, hash and resume name the targets it ran)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import SpecError
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.results.store import RunStore


def two_outputs(tmp_path):
    rng = np.random.default_rng(0)
    frames = [pd.DataFrame({SEGMENT: name, TIME: np.arange(120) * 0.1, "u": rng.normal(size=120),
                            "y1": rng.normal(size=120) + 3, "y2": rng.normal(size=120) - 2, "aux": rng.normal(size=120)})
              for name in ("a", "b")]
    schema = Schema((Column("u", "input"), Column("y1", "output"), Column("y2", "output"), Column("aux", "internal")))
    return write_dataset(Dataset("two", pd.concat(frames, ignore_index=True), schema, 0.1, {}), tmp_path / "two.parquet")


def spec(dataset, targets):
    return from_dict({"name": "all", "dataset": str(dataset), "targets": targets, "mode": "simulation",
                      "repetitions": 1, "train_size": 0, "split": {"kind": "records", "train": ["a"], "test": ["b"]},
                      "selection": {"kind": "none"}, "methods": ["naive-mean"]}, origin="test")


def test_all_means_every_output_column_and_the_run_stores_the_list(tmp_path):
    s = spec(two_outputs(tmp_path), "all")
    assert s.all_targets and s.targets == ("all",)
    result = run_experiment(s, RunStore(tmp_path / "runs"), workers=1)
    config = result.run.config()
    assert config["targets"] == ["y1", "y2"] and "all_targets" not in config
    table = result.run.metrics()
    assert sorted(set(table["target"])) == ["y1", "y2"]
    explicit = spec(tmp_path / "two.parquet", ["y1", "y2"])
    assert config == explicit.to_dict()  # the same experiment as naming the outputs


def test_a_list_naming_all_is_a_column_called_all(tmp_path):
    s = spec(two_outputs(tmp_path), ["all"])
    assert not s.all_targets
    with pytest.raises(Exception, match="'all'"):
        run_experiment(s, RunStore(tmp_path / "runs"), workers=1)


def test_all_on_a_dataset_without_outputs_is_one_line():
    s = spec("x.parquet", "all")
    with pytest.raises(SpecError, match=r"targets = \"all\" but the dataset has no output column"):
        s.with_outputs([])
