"""README 'Writing a method' -> 'A simulating method': the example runs, conforms and is exact on its own model class."""

from __future__ import annotations

import importlib
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.schema import Column, Schema
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.registry import load_plugin_file
from enginebench.results.store import RunStore
from enginebench.testing import check_method

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_example() -> str:
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Writing a method"):]
    section = section[: section.index("\n## ", 1)]
    blocks = [b for b in re.findall(r"```python\n(.*?)```", section, re.S) if "class FirstOrder" in b]
    assert len(blocks) == 1, "README's 'Writing a method' must hold one FirstOrder example"
    return blocks[0]


@pytest.fixture(scope="module")
def plugin(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plugin") / "readme_first_order.py"  # a real module: it pickles by reference
    path.write_text(readme_example(), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def FirstOrder(plugin):
    import sys

    sys.path.insert(0, str(plugin.parent))
    try:
        yield importlib.import_module(plugin.stem).FirstOrder
    finally:
        sys.path.remove(str(plugin.parent))


THETA = np.array([[0.8], [0.5], [-0.25], [0.3]])  # y[k+1] = 0.8 y[k] + 0.5 u1[k] - 0.25 u2[k] + 0.3


def records(lengths=(300, 200), seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    frames = []
    for name, n in zip(("est", "val"), lengths):
        u = rng.normal(size=(n, 2))
        y = np.empty(n)
        y[0] = 1.0
        for k in range(n - 1):
            y[k + 1] = np.r_[y[k], u[k], 1.0] @ THETA[:, 0]
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(n) * 0.01, "u1": u[:, 0], "u2": u[:, 1], "y": y}))
    schema = Schema((Column("u1", "input", "V"), Column("u2", "input", "V"), Column("y", "output", "V")))
    return Dataset("first-order", pd.concat(frames, ignore_index=True), schema, 0.01, {"provenance": "test"})


def test_the_example_passes_the_simulation_suite(FirstOrder):
    report = check_method(FirstOrder)
    assert report.modes == ("simulation",) and report.passed[-1] == "bad-input[simulation]"


def test_the_example_recovers_its_model_and_simulates_from_the_init_window(FirstOrder):
    ds = records()
    raw = RawSegments.from_dataset(ds)
    train = SamplePool(raw, ["y"], "simulation").materialize()
    est = train.take(np.arange(300))
    m = FirstOrder()
    fitted = m.fit(est, {}, np.random.default_rng(0))
    np.testing.assert_allclose(fitted["theta"], THETA, atol=1e-10)
    assert m.describe(fitted)["largest_pole"] == pytest.approx(0.8) and m.describe(fitted)["warnings"] == []
    N = 7
    test = SamplePool(raw, ["y"], "simulation", init_samples=N).materialize()
    preds = m.predict(fitted, test.without_targets())
    assert not preds.diverged.any()
    for p, s in zip(preds, test.segments):
        assert p.shape == (len(s.t) - N, 1)
        np.testing.assert_allclose(p, s.y, rtol=1e-9, atol=1e-9)  # its own model class: exact in free run
    # it starts from y_init[-1]: another last window sample shifts the whole trajectory, earlier ones do nothing
    view = test.without_targets()
    seg = view.segments[1]
    moved = replace(view, segments=(replace(seg, y_init=seg.y_init + 1.0),))
    np.testing.assert_allclose(m.predict(fitted, moved)[0] - preds[1], 0.8 ** np.arange(1, len(seg.rows) + 1)[:, None],
                               rtol=1e-9, atol=1e-12)


def test_the_example_runs_as_a_plugin_under_the_identification_protocol(plugin, tmp_path):
    data = write_dataset(records(), tmp_path / "fo.parquet")
    spec = from_dict({
        "name": "fo", "dataset": str(data), "targets": ["y"], "mode": "simulation", "repetitions": 1,
        "train_size": 0, "init_samples": 10, "split": {"kind": "records", "train": ["est"], "test": ["val"]},
        "selection": {"kind": "none"}, "methods": {"naive-mean": {}, "my-first-order": {}},
    }, origin="test")
    load_plugin_file(plugin)  # what --plugin does
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1, plugins=(str(plugin),)).run
    assert run.job_notes() == {"failed": {}, "warnings": {}}
    m = run.metrics()
    mae = m[(m["split"] == "test") & (m["metric"] == "mae")].set_index("method")["value"]
    assert mae["my-first-order"] < 1e-8 < mae["naive-mean"]
