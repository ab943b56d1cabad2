"""Two jobs never share a file: job keys are injective (names differing only in punctuation, '__' inside a
name, windows equal to %g), duplicates are refused in the spec, and a run checks every planned job is stored."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import SpecError
from enginebench.experiments.jobs import Job, key_part
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.results.store import RunStore

NAMES = ["y a", "y-a", "y_a", "y.a", "NOx (ppm)", "NOx [ppm]", "a__b", "a_", "_a", "a~5F", "~", "", "é", "e\u0301",
         "naive mean", "naive-mean", "w1__x", "a__w0__b"]


def test_key_parts_are_injective_and_never_hold_the_separator():
    parts = [key_part(n) for n in NAMES]
    assert len(set(parts)) == len(parts)
    assert all("__" not in p and not p.startswith("_") and not p.endswith("_") for p in parts)
    assert key_part("t_cat") == "t_cat" and key_part("naive-mean") == "naive-mean"  # plain names as before


def test_job_keys_are_injective_over_every_coordinate():
    jobs = [Job(t, w, s, m, r) for t, s, m in itertools.product(NAMES[:8], ["published", "a__w0__b"], NAMES[-4:])
            for w in (0.0, 1.0, 1.0000001, 30.0) for r in (0, 1)]
    assert len({j.key for j in jobs}) == len(jobs)
    assert Job("a", 0.0, "b__w0__c", "m", 0).key != Job("a__w0__b", 0.0, "c", "m", 0).key


def test_targets_differing_only_in_punctuation_are_stored_apart(tmp_path):
    rng = np.random.default_rng(0)
    frames = [pd.DataFrame({SEGMENT: f"s{k}", TIME: np.arange(50.0), "u": rng.normal(size=50),
                            "y a": rng.normal(size=50), "y-a": rng.normal(size=50) + 5}) for k in range(2)]
    schema = Schema((Column("u", "input"), Column("y a", "output"), Column("y-a", "output")))
    path = write_dataset(Dataset("p", pd.concat(frames, ignore_index=True), schema, 1.0, {}), tmp_path / "p.parquet")
    spec = from_dict({"name": "p", "dataset": str(path), "targets": ["y a", "y-a"], "repetitions": 2,
                      "train_size": 0, "split": {"kind": "records", "train": ["s0"], "test": ["s1"]},
                      "selection": {"kind": "none"}, "methods": ["naive-mean"]}, origin="test")
    result = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1)
    assert result.n_jobs == 4 and len(result.run.job_files()) == 4
    m = result.run.metrics()
    means = m[(m["metric"] == "mae")].groupby("target")["value"].count()
    assert dict(means) == {"y a": 2, "y-a": 2}


def test_windows_listed_twice_are_refused():
    with pytest.raises(SpecError, match="'windows' lists 1 more than once"):
        from_dict({"dataset": "d", "targets": ["y"], "methods": ["naive-mean"], "mode": "window", "windows": [1, 1.0]},
                  origin="test")
