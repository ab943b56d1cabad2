"""The synthetic turboshaft flight simulator: determinism, layout, split and physical invariants."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import curve_fit

from enginebench.datasets.turboshaft import generate
from enginebench.datasets.turboshaft.atmosphere import intake, isa
from enginebench.datasets.turboshaft.closed_loop import LoopInputs, simulate_closed_loop
from enginebench.datasets.turboshaft.engine import fuel_limits, simulate_engine
from enginebench.datasets.turboshaft.generator import DT, SENSOR_NOISE, simulate_flights
from enginebench.datasets.turboshaft.params import draw_engines, nominal_engines
from enginebench.datasets.turboshaft.profile import CLIMB, CRUISE, DESCENT, GROUND, HOVER
from enginebench.errors import DataError

HOURS = 0.3


@pytest.fixture(scope="module")
def ds():
    return generate(HOURS, seed=1)


@pytest.fixture(scope="module")
def sim():
    return simulate_flights(HOURS, np.random.default_rng(5))


def _recorded(sim) -> np.ndarray:
    """(T, batch) mask of the recorded samples of each trajectory (pre-roll excluded)."""
    t = np.arange(sim.inputs.col.shape[0])[:, None]
    return (t >= sim.preroll) & (t < sim.preroll + sim.piece_length[None, :])


def _step_batch(collectives, before=0.6, seconds=150.0, altitude=500.0, airspeed=0.0):
    """Closed loop at fixed conditions: collective ``before`` for 5 s, then each of ``collectives``."""
    cs = np.asarray(collectives, dtype=float)
    T = int(round(seconds / DT))
    t = np.arange(T) * DT
    col = np.where(t[:, None] < 5.0, before, cs[None, :])
    shape = col.shape
    v = np.full(shape, airspeed)
    p, temp, rho = isa(np.full(shape, altitude), 10.0)
    p0, t1 = intake(p, temp, rho, v)
    inputs = LoopInputs(col=col, airspeed=v, p0=p0, t1=t1, rho=rho,
                        nr_ref=np.full(shape, 100.0), load_factor=np.ones(shape))
    return inputs, simulate_closed_loop(inputs, draw_engines(np.random.default_rng(0)))


# -- determinism ---------------------------------------------------------------------
def test_same_seed_same_content_different_seed_differs(ds):
    again = generate(HOURS, seed=1)
    assert again.content_hash() == ds.content_hash()
    assert again.meta == ds.meta
    other = generate(HOURS, seed=2)
    assert other.content_hash() != ds.content_hash()


def test_progress_is_reported_monotonically_up_to_one():
    calls: list[float] = []
    generate(0.1, seed=3, progress=calls.append)
    assert len(calls) > 5
    assert all(0.0 <= a <= b <= 1.0 for a, b in zip(calls, calls[1:]))
    assert calls[-1] == 1.0


@pytest.mark.parametrize("hours", [0.0, -1.0, 0.05, float("nan")])
def test_too_short_or_invalid_duration_is_rejected(hours):
    with pytest.raises(DataError, match=r"hours=.* use hours >= 0.1"):
        generate(hours, seed=0)


# -- layout, roles, split --------------------------------------------------------------
def test_columns_roles_and_units(ds):
    s = ds.schema
    assert s.inputs == ["COL", "NR", "airspeed", "P0", "T1"]
    assert s.outputs == ["TRQ", "WF"]
    assert s.internals == ["NG", "NP"]
    assert s.groups == ["flight", "engine"]
    assert all(c.unit for c in s.columns)
    assert (s["WF"].unit, s["P0"].unit, s["T1"].unit, s["airspeed"].unit) == ("kg/h", "kPa", "K", "kn")
    assert ds.dt == pytest.approx(1.0 / 12.0)
    assert ds.meta["synthetic"] is True
    assert ds.meta["provenance"] == "synthetic: enginebench turboshaft generator v1, seed 1"
    assert ds.meta["license"]


def test_duration_segments_and_ids(ds):
    f = ds.frame
    assert len(f) == 2 * int(round(HOURS * 3600 * 12))  # HOURS recorded on each of two engines
    ids = ds.segment_ids
    assert all(re.fullmatch(r"F\d{3}-E[12]-T\d{2}", sid) for sid in ids)
    first = f.drop_duplicates("segment").set_index("segment")
    for sid in ids:
        flight, engine, _ = sid.split("-")
        assert (first.loc[sid, "flight"], first.loc[sid, "engine"]) == (flight, engine)
    # fixed period within every segment, both engines of a trajectory on the same clock
    for sid, part in ds.segments():
        assert np.allclose(np.diff(part["time"].to_numpy()), DT)
    e1 = f[f["engine"] == "E1"]
    e2 = f[f["engine"] == "E2"]
    assert np.array_equal(e1["time"].to_numpy(), e2["time"].to_numpy())
    assert np.array_equal(e1["segment"].str.replace("-E1-", "-E2-").to_numpy(), e2["segment"].to_numpy())


def test_published_split_keeps_whole_flights_together(ds):
    split = ds.meta["published_split"]
    sides = [set(split[k]) for k in ("train", "validation", "test")]
    assert all(sides)
    assert sides[0].isdisjoint(sides[1]) and sides[0].isdisjoint(sides[2]) and sides[1].isdisjoint(sides[2])
    assert set().union(*sides) == set(ds.segment_ids)
    flight_side = {}
    for k, side in enumerate(sides):
        for sid in side:
            flight = sid.split("-")[0]
            assert flight_side.setdefault(flight, k) == k  # both engines, all trajectories: one side
    counts = np.bincount(list(flight_side.values()), minlength=3)
    assert counts.tolist() == [3, 1, 1]  # 5 flights: about 60/20/20


def test_engines_differ_slightly(ds):
    f = ds.frame
    e1 = f[f["engine"] == "E1"]
    e2 = f[f["engine"] == "E2"]
    rel = np.abs(e1["WF"].to_numpy() - e2["WF"].to_numpy()).mean() / e1["WF"].abs().mean()
    noise_only = np.sqrt(2) * SENSOR_NOISE["WF"] * np.sqrt(2 / np.pi) / e1["WF"].abs().mean()
    assert 2 * noise_only < rel < 0.1


# -- physical invariants -----------------------------------------------------------------
def test_fuel_flow_within_limits_everywhere(sim, ds):
    lim = fuel_limits(sim.inputs.p0, sim.inputs.t1)
    wf = sim.outputs["WF"]  # (T, batch, engines), noise-free
    assert np.all(wf >= lim["wf_min"][..., None] * (1 - 1e-12))
    assert np.all(wf <= lim["wf_max"][..., None] * (1 + 1e-12))
    rate = np.diff(wf, axis=0) / DT
    assert np.all(rate <= lim["rate_up"][:-1, :, None] * (1 + 1e-9))
    assert np.all(-rate <= lim["rate_down"][:-1, :, None] * (1 + 1e-9))
    # the recorded (noisy) WF stays within the limits computed from the recorded P0, T1
    rec = fuel_limits(ds.frame["P0"].to_numpy(), ds.frame["T1"].to_numpy())
    wf_rec = ds.frame["WF"].to_numpy()
    tol = 6 * SENSOR_NOISE["WF"] + 1.0
    assert np.all(wf_rec >= rec["wf_min"] - tol) and np.all(wf_rec <= rec["wf_max"] + tol)


def test_limits_engage_on_collective_steps():
    inputs, out = _step_batch([0.0, 0.9])
    lim = fuel_limits(inputs.p0, inputs.t1)
    wf = out["WF"]
    rate = np.diff(wf, axis=0) / DT
    # collective dump: deceleration limit, then the minimum fuel flow
    assert np.isclose(-rate[:, 0, :], lim["rate_down"][:-1, 0, None]).any()
    assert np.isclose(wf[:, 0, :], lim["wf_min"][:, 0, None]).any()
    # collective pull: acceleration limit
    assert np.isclose(rate[:, 1, :], lim["rate_up"][:-1, 1, None]).any()
    assert np.all(wf >= lim["wf_min"][..., None] * (1 - 1e-12))
    assert np.all(rate <= lim["rate_up"][:-1, :, None] * (1 + 1e-9))


def test_rotor_speed_regulated_in_steady_phases(sim, ds):
    rec = _recorded(sim)
    steady = rec & np.isin(sim.phase, (GROUND, HOVER, CLIMB, CRUISE, DESCENT)) & (sim.phase_age >= 30.0)
    assert steady.sum() > 1000
    err = sim.outputs["NR"] - sim.inputs.nr_ref
    assert np.abs(err[steady]).max() < 2.0
    assert np.median(np.abs(err[rec])) < 0.5
    # the recorded NR stays near its set-points (100 % or 102 %) everywhere
    nr = ds.frame["NR"].to_numpy()
    assert np.all((nr > 94.0) & (nr < 106.0))
    assert np.quantile(np.minimum(np.abs(nr - 100), np.abs(nr - 102)), 0.95) < 1.5


def test_torque_and_ng_rise_with_collective_at_fixed_conditions():
    cs = [0.2, 0.35, 0.5, 0.65, 0.8]
    _, out = _step_batch(cs)
    last = slice(-12, None)
    trq = out["TRQ"][last].mean(axis=0)  # (batch, engines), settled
    ng = out["NG"][last].mean(axis=0)
    wf = out["WF"][last].mean(axis=0)
    for y in (trq, ng, wf):
        assert np.all(np.diff(y, axis=0) > 0)
    assert np.all(np.abs(out["TRQ"][-1] - out["TRQ"][-121]) < 0.05)  # steady after 150 s
    assert np.all(np.abs(out["NR"][-1] - 100.0) < 0.2)  # isochronous: back to the set-point


def test_intake_pressure_falls_with_altitude(sim):
    p, t, rho = isa(np.array([0.0, 1000.0, 2000.0, 3000.0]))
    np.testing.assert_allclose(p, [101.325, 89.8746, 79.4952, 70.1085], atol=0.002)  # ICAO standard atmosphere table
    np.testing.assert_allclose(t, [288.15, 281.65, 275.15, 268.65])
    p0, t1 = intake(p, t, rho, np.full(4, 100.0))
    assert np.all(np.diff(p0) < 0) and np.all(p0 > p)
    for prof in sim.flights:
        flying = prof.altitude > prof.altitude.min() + 50
        if flying.sum() > 100:
            assert np.corrcoef(prof.altitude[flying], prof.p0[flying])[0, 1] < -0.9


def _first_order(x, a, b, tau):
    return a + b * (1 - np.exp(-x / tau))


def _two_modes(x, a, b, tau, c, tau2):
    return a + b * (1 - np.exp(-x / tau)) + c * (1 - np.exp(-x / tau2))


def test_slow_thermal_mode_leaves_a_tail_a_first_order_fit_misses():
    T = int(240 / DT)
    t = np.arange(T) * DT
    wf = np.repeat(np.where(t >= 10.0, 210.0, 150.0)[:, None], 2, axis=1)
    nominal = nominal_engines(2)
    eng = replace(nominal, kappa=np.array([nominal.kappa[0], 0.0]))  # with and without heat soak
    trq = simulate_engine(wf, 101.325, 288.15, eng, DT)["TRQ"]
    x = t[t >= 10.0] - 10.0
    residual, tail = [], []
    for k in range(2):
        y = trq[t >= 10.0, k]
        step = y[-1] - trq[0, k]
        p1, _ = curve_fit(_first_order, x, y, p0=[y[0], step, 1.0])
        residual.append(np.sqrt(np.mean((y - _first_order(x, *p1)) ** 2)) / step)
        tail.append((y[-1] - y[x == 8.0][0]) / step)  # what is still to come 8 s after the step
        if k == 0:
            p2, _ = curve_fit(_two_modes, x, y, p0=[y[0], step, 1.0, 0.05 * step, 40.0])
            two = np.sqrt(np.mean((y - _two_modes(x, *p2)) ** 2)) / step
            assert 20.0 < p2[4] < 100.0  # the slow mode's time constant: tens of seconds
            assert two < residual[0] / 3
    assert tail[0] > 0.03 and abs(tail[1]) < 0.005
    assert residual[0] > 2.5 * residual[1]
