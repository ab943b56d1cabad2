"""The synthetic marine-diesel data set: structure, roles, split, plausibility, determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME
from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.calibration import calibrate_to_fat
from enginebench.datasets.marine_diesel.fat import simulator_fat
from enginebench.datasets.marine_diesel.generate import NAME, generate
from enginebench.datasets.marine_diesel.pm import PM_NAME, simulate_frame
from enginebench.errors import DataError


@pytest.fixture(scope="module")
def small():
    calls: list[float] = []
    ds = generate("small", seed=0, progress=calls.append)
    return ds, calls


def test_structure_roles_and_units(small):
    ds, calls = small
    assert ds.name == NAME and ds.dt == C.DT_LOG_S
    assert len(ds) == int(C.SMALL_HOURS * 3600 / C.DT_LOG_S)
    sch = ds.schema
    assert sch.outputs == ["t_exhaust_turbine_inlet", "t_exhaust_turbine_outlet"]
    assert set(sch.internals) == {f"t_exhaust_{w}_{b}" for w in ("cylinders", "before_turbine", "after_turbine")
                                  for b in "ab"}
    assert 40 <= len(sch.names()) <= 50 and len(sch.inputs) >= 35
    assert all(c.unit for c in sch.columns)
    assert sch["p_charge_air"].unit == "bar abs" and sch["t_bearing_4"].unit == "degC"
    assert ds.frame[sch.names()].notna().all().all()
    assert np.isfinite(ds.frame[sch.names()].to_numpy()).all()
    # progress: increasing fractions ending at 1
    assert calls[-1] == 1.0 and all(b >= a for a, b in zip(calls, calls[1:]))


def test_meta_labels_it_synthetic_with_a_temporal_split(small):
    ds, _ = small
    meta = ds.meta
    assert meta["synthetic"] is True
    assert meta["provenance"].startswith("synthetic: enginebench marine-diesel generator v")
    assert "seed 0" in meta["provenance"] and meta["license"]
    assert meta["physical_model"] == PM_NAME
    json.dumps(meta)                              # storable as Parquet schema metadata
    split = meta["published_split"]
    assert set(split["train"]).isdisjoint(split["test"])
    assert set(split["train"]) | set(split["test"]) == set(ds.segment_ids)
    times = ds.frame.groupby(SEGMENT)[TIME].agg(["min", "max"])
    assert times.loc[split["train"], "max"].max() < times.loc[split["test"], "min"].min()
    man = meta["segment_manoeuvre_fraction"]
    for part in ("train", "test"):               # both modes on both sides
        fr = np.array([man[s] for s in split[part]])
        assert fr.max() > 0.0 and fr.min() < 1.0


def test_segments_are_continuous_at_the_logging_period(small):
    ds, _ = small
    for _, part in ds.segments():
        dt = np.diff(part[TIME].to_numpy())
        np.testing.assert_allclose(dt, C.DT_LOG_S)
        assert len(part) >= 100


def test_targets_are_bank_means_of_the_internal_channels(small):
    ds, _ = small
    f = ds.frame
    np.testing.assert_allclose(f["t_exhaust_turbine_inlet"],
                               0.5 * (f["t_exhaust_before_turbine_a"] + f["t_exhaust_before_turbine_b"]))
    np.testing.assert_allclose(f["t_exhaust_turbine_outlet"],
                               0.5 * (f["t_exhaust_after_turbine_a"] + f["t_exhaust_after_turbine_b"]))


def test_values_are_physically_plausible(small):
    ds, _ = small
    f = ds.frame
    assert f["engine_speed"].between(370.0, 1045.0).all()
    assert f["engine_speed"].min() < 450.0 and f["engine_speed"].max() > 950.0      # idle to full speed
    assert f["p_charge_air"].between(0.9, 4.8).all()
    assert f["p_exhaust_receiver"].between(0.9, 4.5).all()
    assert f["t_exhaust_turbine_inlet"].between(100.0, 700.0).all()
    assert f["t_exhaust_turbine_inlet"].quantile(0.9) > 450.0
    assert (f["t_exhaust_turbine_inlet"].mean() > f["t_exhaust_turbine_outlet"].mean() + 30.0)
    assert f["t_ht_water_before_cooler"].between(55.0, 95.0).all()
    assert f["t_lube_oil_after_engine"].mean() > f["t_lube_oil_before_engine"].mean()
    assert (f["t_bearing_5"].mean() > f["t_bearing_1"].mean())                      # mid-engine bearings
    assert f["fuel_rack"].between(0.0, 101.0).all()
    # the outputs follow the fuel per cycle: hottest at high rack, coldest near idle
    lo, hi = f["fuel_rack"].quantile([0.1, 0.9])
    t_in = f["t_exhaust_turbine_inlet"]
    assert t_in[f["fuel_rack"] >= hi].mean() > t_in[f["fuel_rack"] <= lo].mean() + 150.0


def test_pm_tracks_the_synthetic_data(small):
    """The PM calibrated on this engine's FAT follows the trend but is biased (egt-hybrid sec. 5)."""
    ds, _ = small
    params, _ = calibrate_to_fat(simulator_fat(0))
    pred = simulate_frame(params, ds.frame, ds.dt)
    for name in ds.schema.outputs:
        y = ds.frame[name].to_numpy()
        assert np.corrcoef(pred[name], y)[0, 1] > 0.9
        assert 2.0 < np.mean(np.abs(pred[name] - y)) < 80.0


def test_same_seed_same_data_other_seed_other_data(small):
    ds, _ = small
    again = generate("small", seed=0)
    assert again.content_hash() == ds.content_hash()
    other = generate("small", seed=1)
    assert other.content_hash() != ds.content_hash()
    assert "seed 1" in other.meta["provenance"]


def test_bad_arguments_are_rejected():
    with pytest.raises(DataError, match="unknown size 'huge'"):
        generate("huge")
    with pytest.raises(DataError, match="seed"):
        generate("small", seed=-1)
