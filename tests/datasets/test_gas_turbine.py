"""The real gas-turbine data: import, published split, the expansion model, a hybrid run."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.datasets.gas_turbine.importer import import_directory
from enginebench.datasets.gas_turbine.physics import TATExpansionModel
from enginebench.datasets.splits import published
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.results.store import RunStore
from enginebench.results.summary import summarize

pytestmark = pytest.mark.shared_data


@pytest.fixture
def dataset(gas_turbine_dir):
    return import_directory(gas_turbine_dir)


def test_import_gives_the_documented_records(dataset):
    assert len(dataset) == 36733
    assert dataset.segment_ids == ["2011", "2012", "2013", "2014", "2015"]
    assert dataset.schema.outputs == ["TAT", "CO", "NOX"]
    (split,) = published(dataset)
    assert (len(split.train), len(split.test)) == (7411 + 7628 + 7152, 7158 + 7384)
    assert np.all(np.diff(dataset.frame["time"].to_numpy()) == 3600.0)


def test_expansion_model_is_physical_and_beats_the_mean(dataset):
    (split,) = published(dataset)
    tr, te = split.train.frame, split.test.frame
    pm = TATExpansionModel()
    params = pm.calibrate([{c: tr[c].to_numpy() for c in (*pm.inputs, "TAT")}])
    # k = eta_p (gamma - 1) / gamma: about 0.2 for hot combustion gas (gamma ~ 1.33, eta_p ~ 0.85)
    assert 0.15 < params["k"] < 0.3
    assert params["rms_residual_degC"] < 3.0
    pred = pm.simulate(params, {c: te[c].to_numpy() for c in pm.inputs}, 3600.0)["TAT"]
    mae_pm = np.mean(np.abs(pred - te["TAT"].to_numpy()))
    mae_mean = np.mean(np.abs(tr["TAT"].mean() - te["TAT"].to_numpy()))
    assert mae_pm < mae_mean


def test_pm_krls_and_hybrid_run_at_two_windows(gas_turbine_dir, tmp_path, monkeypatch):
    from enginebench.datasets import catalog

    monkeypatch.setenv("ENGINEBENCH_DATA", str(tmp_path / "data"))
    catalog.import_builtin("gas-turbine-emissions", gas_turbine_dir)
    spec = from_dict({
        "name": "gt-tat-small", "dataset": "gas-turbine-emissions", "targets": ["TAT"], "mode": "window",
        "windows": [0, 3600], "repetitions": 2, "train_size": 200, "selection": {"resamples": 1},
        "methods": {"pm": {}, "krls": {"gamma_grid": [-2, 0, 3], "lambda_grid": [-3, -1, 3]},
                    "mtl-krls": {"gamma_grid": [-2, 0, 3], "lambda_grid": [-3, -1, 3], "theta_grid": [-2, 2, 3]}},
    }, origin="test")
    result = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1)
    assert result.n_failed == 0
    summary = summarize(result.run.metrics())
    mae = summary[summary["metric"] == "mae"].set_index(["window", "method"])["mean"]
    assert set(mae.index) == {(w, m) for w in (0.0, 3600.0) for m in ("pm", "krls", "mtl-krls")}
    assert mae[(3600.0, "krls")] < mae[(0.0, "krls")]  # the past hour of TAT is informative
    meta = result.run.job_meta("TAT__w3600__published__mtl-krls__r000")
    assert {"gamma", "lambda", "theta"} == set(meta["params"])
    assert 0.15 < meta["describe"]["pm_params"]["k"] < 0.3


def test_declared_pressure_units_match_the_values_and_the_docs(dataset):
    """CDP is labelled mbar by the UCI source, but its values are bar: the schema, the notes and docs/data.md say bar."""
    from pathlib import Path

    from enginebench.datasets.gas_turbine.importer import CDP_UNIT_NOTE

    units = {c.name: c.unit for c in dataset.schema.columns}
    assert (units["CDP"], units["AP"], units["GTEP"], units["AFDP"]) == ("bar", "mbar", "mbar", "mbar")
    f = dataset.frame
    to_mbar = {"bar": 1000.0, "mbar": 1.0}
    ratio = f["CDP"] * to_mbar[units["CDP"]] / (f["AP"] * to_mbar[units["AP"]])
    assert ratio.between(8.0, 20.0).all()  # an industrial gas turbine's pressure ratio, in the declared units
    assert CDP_UNIT_NOTE in dataset.meta["notes"]
    docs = (Path(__file__).resolve().parents[2] / "docs" / "data.md").read_text(encoding="utf-8")
    row = next(line for line in docs.splitlines() if line.startswith("| `gas-turbine-emissions`"))
    assert "CDP **bar**" in row and "AP, AFDP, GTEP mbar" in row


def test_the_published_baseline_was_made_from_this_importers_data(dataset):
    """`tox -e guard` imports the data afresh: the baseline's dataset hash must be the importer's (schema and units
    included), or guard warns that the dataset differs."""
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "results" / "published" / "gas-turbine-nox-quick.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    hashes = {doc["dataset_hash"], *(r["dataset_hash"] for r in doc["reproducibility"]["reruns"])}
    assert hashes == {dataset.content_hash()}
