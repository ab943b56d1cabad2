"""Shared fixtures: a small synthetic dataset with a known input-output relation."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import settings

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.schema import Column, Schema
from helpers import make_toy

# CI (CI=true) draws the property tests' examples deterministically, so that a landing never depends on the
# luck of a random draw; a developer's run keeps drawing new examples (and reports any it finds).
settings.register_profile("ci", derandomize=True, database=None)
if os.environ.get("CI"):
    settings.load_profile("ci")

SHARED = Path(os.environ.get("ENGINEBENCH_SHARED", Path(__file__).resolve().parents[1].parent / "shared"))
GAS_TURBINE_DIR = SHARED / "data" / "gas-turbine-emissions"


@pytest.fixture
def toy() -> Dataset:
    return make_toy()


@pytest.fixture
def toy_parquet(tmp_path, toy) -> Path:
    from enginebench.datasets.io import write_dataset

    return write_dataset(toy, tmp_path / "toy.parquet")


@pytest.fixture
def gas_turbine_dir() -> Path:
    if not GAS_TURBINE_DIR.is_dir():
        pytest.skip(f"shared data not found at {GAS_TURBINE_DIR} (set ENGINEBENCH_SHARED)")
    return GAS_TURBINE_DIR
