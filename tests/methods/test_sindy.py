"""SINDy: coefficient recovery on known controlled systems, the batched simulator against
pysindy's own ``simulate`` (scipy solve_ivp), divergence accounting, and determinism."""

from __future__ import annotations

import json
import pickle
from dataclasses import replace
from typing import Callable

import numpy as np
import pandas as pd
import pysindy as ps
import pytest
from scipy.integrate import solve_ivp
from sklearn.preprocessing import PolynomialFeatures

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.method import SegmentPredictions, grid_points
from enginebench.methods.numerics.derivatives import window_bounds
from enginebench.methods.sindy import SINDy
from enginebench.methods.sindy_library import differentiate, library_features, raw_coefficients, simulate_batch
from enginebench.samples import Samples

DT = 0.1


def _samples(
    f: Callable[[np.ndarray, np.ndarray], np.ndarray],
    *,
    seed: int,
    durations: tuple[float, ...] = (15.0, 15.0, 15.0),
    u_offset: float = 0.0,
    u_amp: float = 1.0,
    x0_range: tuple[float, float] = (-1.0, 1.0),
) -> Samples:
    """Segments of dx/dt = f(x, u) with a smooth random input, integrated to 1e-10 by scipy."""
    rng = np.random.default_rng(seed)
    frames = []
    for k, dur in enumerate(durations):
        a, w, ph = rng.uniform(0.5, 1.5, 3), rng.uniform(0.3, 2.0, 3), rng.uniform(0, 2 * np.pi, 3)

        def u(t, a=a, w=w, ph=ph):
            return u_offset + u_amp * (a[:, None] * np.sin(w[:, None] * np.atleast_1d(t) + ph[:, None])).sum(axis=0)

        t = np.arange(0.0, dur, DT)
        sol = solve_ivp(lambda tt, x: f(x, u(tt)), (0.0, t[-1]), [rng.uniform(*x0_range)], t_eval=t,
                        rtol=1e-10, atol=1e-10)
        assert sol.success
        frames.append(pd.DataFrame({"segment": f"s{k}", "time": t + 1000.0 * k, "u": u(t), "y": sol.y[0]}))
    frame = pd.concat(frames, ignore_index=True)
    ds = Dataset("toy", frame, Schema.from_roles({"u": "input", "y": "output"}, {"u": "1", "y": "K"}), DT)
    return make_samples(ds, ["y"], mode="simulation")


def _linear(x, u):
    return -2.0 * x + 3.0 * u


def _quadratic(x, u):
    return -x - 0.5 * x**2 + u


LINEAR = _samples(_linear, seed=1)
QUADRATIC = _samples(_quadratic, seed=2, u_offset=1.2, u_amp=0.25)
RNG = np.random.default_rng(0)


def _raw_terms(fitted) -> dict[str, float]:
    """Raw-unit coefficients (d y / dt in K/s) by monomial name."""
    names = ps.PolynomialLibrary(degree=fitted.params["degree"]).fit(np.zeros((1, 2))).get_feature_names(["y", "u"])
    return dict(zip(names, raw_coefficients(fitted)[0]))


# ----------------------------------------------------------------------------- (1) recovery
def test_recovers_linear_controlled_system():
    """dx/dt = -2x + 3u from 4 segments, default (total-variation) derivatives, degree-2 library."""
    m = SINDy()
    fitted = m.fit(LINEAR, {"degree": 2, "threshold": 0.05, "alpha": 1e-4}, RNG)
    raw = _raw_terms(fitted)
    assert raw["y"] == pytest.approx(-2.0, rel=5e-3)
    assert raw["u"] == pytest.approx(3.0, rel=5e-3)
    # every quadratic term was thresholded away, exactly
    assert raw["y^2"] == 0.0 and raw["y u"] == 0.0 and raw["u^2"] == 0.0
    # the standardised intercept (mean dx/dt over std x, small) is thresholded; what is left is ~0
    assert abs(raw["1"]) < 0.1
    d = m.describe(fitted)
    # in standardised coordinates the true model is a y~ + b u~ + c with c = mean(dx/dt) / std(x) ~ 0
    assert d["term_count"] == 2
    assert d["feature_names"][int(np.flatnonzero(fitted.coef[0])[0])] == "y"
    assert d["degree"] == 2 and d["threshold"] == 0.05 and d["alpha"] == 1e-4
    assert d["equations"][0].startswith("d(y)/dt = ")
    assert " y " in d["equations"][0] + " " and " u" in d["equations"][0]
    assert "y^2" not in d["equations"][0]


def test_recovers_quadratic_controlled_system():
    """dx/dt = -x - 0.5 x^2 + u (stable equilibria for u > 0), degree-3 library."""
    m = SINDy()
    fitted = m.fit(QUADRATIC, {"degree": 3, "threshold": 0.05, "alpha": 1e-4}, RNG)
    raw = _raw_terms(fitted)
    assert raw["y"] == pytest.approx(-1.0, abs=0.02)
    assert raw["y^2"] == pytest.approx(-0.5, abs=0.01)
    assert raw["u"] == pytest.approx(1.0, abs=0.01)
    assert abs(raw["1"]) < 0.01
    for cubic in ("y^3", "y^2 u", "y u^2", "u^3", "y u", "u^2"):
        assert raw[cubic] == 0.0
    # centring x = m + s x~ turns -x - x^2/2 + u into c0 + c1 x~ + c2 x~^2 + c3 u~: four terms
    d = m.describe(fitted)
    assert d["term_count"] == 4
    assert sorted(np.array(d["feature_names"])[fitted.coef[0] != 0]) == ["1", "u", "y", "y^2"]
    assert d["equations_raw"][0].count(" y") >= 2 and "y^3" not in d["equations_raw"][0]


def test_kalman_derivative_also_recovers_and_time_scale_is_only_a_unit():
    m = SINDy(derivative="kalman")
    params = {"degree": 1, "threshold": 0.0, "alpha": 0.0}
    fitted = m.fit(LINEAR, params, RNG)
    raw = _raw_terms(fitted)
    assert raw["y"] == pytest.approx(-2.0, rel=0.02) and raw["u"] == pytest.approx(3.0, rel=0.02)
    # time in units of 2.5 s: standardised coefficients scale by 2.5, raw ones and trajectories do not
    m2 = SINDy(derivative="kalman", time_scale=2.5)
    fitted2 = m2.fit(LINEAR, params, RNG)
    np.testing.assert_allclose(fitted2.coef, 2.5 * fitted.coef, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(list(_raw_terms(fitted2).values()), list(raw.values()), rtol=1e-9, atol=1e-12)
    test = LINEAR.without_targets()
    for a, b in zip(m.predict(fitted, test), m2.predict(fitted2, test)):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_chunked_differentiation_stitches_correctly():
    """A long signal is differentiated in overlapping chunks; the stitched result has no seams."""
    dt = 0.05
    t = np.arange(1000) * dt
    x = np.c_[np.sin(t), np.cos(0.5 * t)]
    exact = np.c_[np.cos(t), -0.5 * np.sin(0.5 * t)]
    d = differentiate(x, dt, kind="kalman", alpha=1e-2, chunk=128, margin=24)
    assert d.shape == x.shape
    assert np.max(np.abs(d[5:-5] - exact[5:-5])) < 1e-5
    tv = differentiate(x[:300], dt, kind="trend_filtered", alpha=1e-3, chunk=128, margin=24)
    # the exact TV minimiser is a staircase (steps of about 0.015 here); a seam would be far larger
    assert np.max(np.abs(tv[10:-10] - exact[10:290])) < 0.02
    one = differentiate(x[:300], dt, kind="trend_filtered", alpha=1e-3, chunk=300, margin=24)
    assert np.max(np.abs(tv[10:-10] - one[10:-10])) < 0.02


# ----------------------------------------------------------------------------- (2) simulator
def test_library_matches_pysindy_transform():
    """library_features(powers_) reproduces pysindy's PolynomialLibrary and model.predict."""
    m = SINDy(derivative="kalman", stlsq="pysindy")
    fitted = m.fit(QUADRATIC, {"degree": 3, "threshold": 0.0, "alpha": 1e-3}, RNG)
    rng = np.random.default_rng(5)
    x, u = rng.normal(size=(50, 1)), rng.normal(size=(50, 1))
    ours = library_features(np.hstack([x, u]), fitted.powers)
    theirs = np.asarray(fitted.model.feature_library.transform(np.hstack([x, u])))
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ours @ fitted.coef.T, np.asarray(fitted.model.predict(x, u=u)), rtol=1e-10, atol=1e-12)
    # the raw-unit expansion is the same function of the raw signals (d y/dt in K/s)
    y_raw, u_raw = x * fitted.state_std + fitted.state_mean, u * fitted.control_std + fitted.control_mean
    raw_rhs = library_features(np.hstack([y_raw, u_raw]), fitted.powers) @ raw_coefficients(fitted).T
    np.testing.assert_allclose(raw_rhs, fitted.state_std * (ours @ fitted.coef.T), rtol=1e-8, atol=1e-10)


def _reference_simulation(fitted, seg) -> np.ndarray:
    """scipy solve_ivp (DOP853, rtol 1e-11) of the fitted model, one call per sample interval with
    the input held; the right-hand side is written out from the term exponents (checked against
    scikit-learn's PolynomialFeatures, whose term order pysindy's library follows)."""
    powers = PolynomialFeatures(degree=fitted.params["degree"]).fit(np.zeros((1, 2))).powers_
    assert np.array_equal(powers, fitted.powers)  # same term order as pysindy's library
    z = [(seg.y0 - fitted.state_mean) / fitted.state_std]
    zu = (seg.U - fitted.control_mean) / fitted.control_std
    for i in range(len(seg.t) - 1):
        rhs = lambda _t, x, v=zu[i]: fitted.coef @ np.prod(np.r_[x, v] ** powers, axis=1)
        sol = solve_ivp(rhs, (seg.t[i], seg.t[i + 1]), z[-1], method="DOP853", rtol=1e-11, atol=1e-12)
        z.append(sol.y[:, -1])
    return np.array(z) * fitted.state_std + fitted.state_mean


def test_batched_simulation_agrees_with_scipy_and_pysindy_simulate():
    m = SINDy(stlsq="pysindy")
    fitted = m.fit(QUADRATIC, {"degree": 2, "threshold": 0.05, "alpha": 1e-4}, RNG)
    test = _samples(_quadratic, seed=7, durations=(12.0, 4.0, 8.0), u_offset=1.2, u_amp=0.25)
    preds = m.predict(fitted, test.without_targets())
    assert isinstance(preds, SegmentPredictions) and not preds.diverged.any()
    assert [p.shape for p in preds] == [(len(s), 1) for s in test.segments]
    seg = test.segments[0]
    ref = _reference_simulation(fitted, seg)
    np.testing.assert_allclose(preds[0], ref, rtol=0, atol=3e-5 * np.ptp(ref))  # RK4 at dt vs exact ZOH
    # the model also tracks the true (continuous-input) system open loop
    assert np.max(np.abs(preds[0] - seg.y)) < 0.03 * np.ptp(seg.y)

    # pysindy's own simulate (scipy LSODA) on a stretch with the input held constant
    n = 15
    const = replace(seg, U=np.full((n, 1), 1.4), t=seg.t[:n], rows=np.arange(n), y=None)
    ours = m.predict(fitted, replace(test, segments=(const,)))[0]
    u_std = (1.4 - fitted.control_mean) / fitted.control_std
    z0 = (seg.y0 - fitted.state_mean) / fitted.state_std
    theirs = fitted.model.simulate(z0, const.t, u=lambda _t: u_std) * fitted.state_std + fitted.state_mean
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-5 * np.ptp(theirs))


def test_batched_equals_one_segment_at_a_time():
    """Unequal lengths share one vectorised loop; each result equals its own single run."""
    rng = np.random.default_rng(3)
    coef = np.array([[0.1, -1.0, 0.5, -0.2, 0.05, 0.0]])
    powers = np.array([[0, 0], [1, 0], [0, 1], [2, 0], [1, 1], [0, 2]])
    lengths = (40, 7, 1, 25)
    x0 = rng.normal(size=(4, 1))
    us = [rng.normal(size=(n, 1)) for n in lengths]
    ts = [np.arange(n) * 0.1 + 3.0 * k for k, n in enumerate(lengths)]
    lo, hi = np.array([-50.0]), np.array([50.0])
    for integrator in ("rk4", "euler"):
        batch, div = simulate_batch(coef, powers, x0, us, ts, lo, hi, integrator=integrator, substeps=2)
        for k in range(4):
            one, d1 = simulate_batch(coef, powers, x0[k:k + 1], us[k:k + 1], ts[k:k + 1], lo, hi,
                                     integrator=integrator, substeps=2)
            np.testing.assert_allclose(batch[k], one[0], rtol=1e-13, atol=1e-15)
            assert div[k] == d1[0]
        assert batch[2].shape == (1, 1) and batch[2][0, 0] == x0[2, 0]


def test_rk4_converges_to_analytic_solution():
    """dx/dt = -x + u with u held at 1: x(t) = 1 + (x0 - 1) e^{-t}; RK4 error is O(h^4)."""
    coef, powers = np.array([[-1.0, 1.0]]), np.array([[1, 0], [0, 1]])
    errs = []
    for h in (0.2, 0.1):
        t = np.arange(0, 5 + h / 2, h)
        traj, _ = simulate_batch(coef, powers, np.array([[3.0]]), [np.ones((t.size, 1))], [t],
                                 np.array([-1e9]), np.array([1e9]))
        errs.append(np.max(np.abs(traj[0][:, 0] - (1 + 2 * np.exp(-t)))))
    assert errs[0] < 1e-4 and 12 < errs[0] / errs[1] < 20


# ----------------------------------------------------------------------------- (3) divergence
def test_unstable_fit_diverges_and_is_counted():
    """Fit on dx/dt = +0.5 x: long test segments leave the envelope, short ones do not."""
    train = _samples(lambda x, u: 0.5 * x + 0.2 * u, seed=4, durations=(4.0, 4.0, 4.0))
    m = SINDy(derivative="kalman")
    fitted = m.fit(train, {"degree": 1, "threshold": 0.02, "alpha": 1e-4}, RNG)
    assert m.describe(fitted)["term_count"] >= 1
    durations = (40.0, 2.0, 40.0, 2.0, 40.0)
    test = _samples(lambda x, u: 0.5 * x + 0.2 * u, seed=9, durations=durations, x0_range=(2.0, 3.0))
    preds = m.predict(fitted, test.without_targets())
    expected = np.array([d > 10 for d in durations])
    np.testing.assert_array_equal(preds.diverged, expected)
    assert int(preds.diverged.sum()) == 3
    env = m.describe(fitted)["envelope"]
    lo, hi = env["lower"][0], env["upper"][0]
    y_train = train.y[:, 0]
    assert hi == pytest.approx(y_train.max() + 10 * np.ptp(y_train))
    for p, div in zip(preds, preds.diverged):
        assert np.all(np.isfinite(p)) and np.all((p >= lo) & (p <= hi))
        if div:
            # held at the last in-envelope value: a flat tail, one RK4 step (growth e^{0.025}) from the edge
            first = int(np.argmax(np.all(p == p[-1], axis=1)))
            assert first < len(p) - 10 and np.all(p[first:] == p[-1])
            assert p[-1, 0] > hi / np.exp(0.5 * DT * 1.2)
    # the open-loop model ran on the unaffected short segments as usual
    assert np.all(np.diff(preds[1][:, 0]) > 0)


def test_non_finite_step_is_flagged_and_held():
    """A model whose first step overflows to inf: flagged, held at y0, batch neighbours untouched."""
    coef, powers = np.array([[1e300, -1.0]]), np.array([[3, 0], [1, 0]])
    x0 = np.array([[10.0], [0.0]])  # 1e300 * 1000 overflows; 0 is an equilibrium
    ts = [np.arange(6) * 0.1] * 2
    traj, div = simulate_batch(coef, powers, x0, [np.zeros((6, 1))] * 2, ts,
                               np.array([-np.inf]), np.array([np.inf]))
    np.testing.assert_array_equal(div, [True, False])
    np.testing.assert_array_equal(traj[0], np.full((6, 1), 10.0))
    np.testing.assert_array_equal(traj[1], np.zeros((6, 1)))


# ----------------------------------------------------------------------------- (4) determinism
def test_deterministic_and_picklable():
    m = SINDy(derivative="kalman")
    params = {"degree": 2, "threshold": 0.05, "alpha": 1e-3}
    a = m.fit(LINEAR, params, np.random.default_rng(1))
    b = SINDy(derivative="kalman").fit(LINEAR, params, np.random.default_rng(99))
    np.testing.assert_array_equal(a.coef, b.coef)
    test = LINEAR.without_targets()
    pa, pb = m.predict(a, test), m.predict(b, test)
    for x, y in zip(pa, pb):
        np.testing.assert_array_equal(x, y)
    c = pickle.loads(pickle.dumps(a))
    for x, y in zip(pa, m.predict(c, test)):
        np.testing.assert_array_equal(x, y)
    assert m.describe(a) == m.describe(c)
    json.dumps(m.describe(a))  # describe artefacts are stored as JSON


def test_predict_grid_shares_work_and_matches_fit_predict():
    m = SINDy(derivative="kalman", degrees=(1, 2), n_thresholds=2, n_alphas=1)
    space = m.search_space(LINEAR)
    assert list(space) == ["order", "degree", "threshold", "alpha"]
    np.testing.assert_array_equal(space["order"], [1, 2])  # both orders by default
    np.testing.assert_allclose(space["threshold"], [1e-2, 0.5])  # relative to each derivative's rms
    assert space["alpha"][0] == pytest.approx(1e-4)
    grid = grid_points(space)
    test = replace(LINEAR, segments=LINEAR.segments[:2]).without_targets()
    out = m.predict_grid(LINEAR, test, grid, RNG)
    assert out.shape == (8, len(test), 1)
    # every model of the grid simulated in one loop: the same numbers as its own predict, bit for bit
    for k, params in enumerate(grid):
        np.testing.assert_array_equal(out[k], np.concatenate(m.predict(m.fit(LINEAR, params, RNG), test)))
    assert m.keeps_grid_models()
    # half the derivative's rms keeps both terms of dx/dt = -2x + 3u
    assert all(m.describe(m.fit(LINEAR, p, RNG))["term_count"] == 2 for p in grid
               if p["threshold"] == 0.5 and p["order"] == 1)


def test_default_grid_is_small_relative_and_the_absolute_scale_keeps_the_seed_ranges():
    space = SINDy().search_space(LINEAR)
    assert [len(v) for v in space.values()] == [2, 3, 4, 3]
    assert space["threshold"][0] == pytest.approx(1e-2) and space["threshold"][-1] == pytest.approx(0.5)
    assert space["alpha"][0] == pytest.approx(1e-4) and space["alpha"][-1] == pytest.approx(1e-1)
    seed = SINDy(threshold_scale="absolute").search_space(LINEAR)["threshold"]
    assert seed[0] == pytest.approx(1e-2) and seed[-1] == pytest.approx(1e3)
    given = SINDy(threshold_scale="absolute", threshold_range=(0.01, 0.01), n_thresholds=1).search_space(LINEAR)
    assert given["threshold"].tolist() == [0.01]


# ----------------------------------------------------------------------------- errors
def test_errors_name_the_problem():
    m = SINDy(derivative="kalman")
    with pytest.raises(MethodError, match="does not support mode 'static'"):
        m.fit(replace(LINEAR, mode="static"), {}, RNG)
    with pytest.raises(MethodError, match="unknown parameter.*lam"):
        m.fit(LINEAR, {"lam": 1.0}, RNG)
    with pytest.raises(MethodError, match="degree must be an integer from 1 to 5, got 0"):
        m.fit(LINEAR, {"degree": 0}, RNG)
    resampled = LINEAR.take(np.array([0, 2, 4, 6, 8, 10]))
    with pytest.raises(MethodError, match="segment 's0' is not a contiguous run of rows"):
        m.fit(resampled, {}, RNG)
    with pytest.raises(MethodError, match="option derivative='tvx'"):
        SINDy(derivative="tvx")
    with pytest.raises(MethodError, match="unknown option"):
        SINDy(bogus=1)
    with pytest.raises(MethodError, match="option threshold_scale='percent'; use 'relative'"):
        SINDy(threshold_scale="percent")
    with pytest.raises(MethodError, match=r"option threshold_range must be \(low, high\)"):
        SINDy(threshold_range=(1.0, 0.1))


def test_a_threshold_that_removes_every_term_gives_a_flagged_flat_line_not_a_divergence():
    """The turboshaft WF quick experiment's threshold 0.1 emptied the model: dx/dt = 0 is simulated exactly
    as y0 held (no envelope is left, nothing is flagged diverged) and describe/notes say why."""
    m = SINDy()
    fitted = m.fit(LINEAR, {"degree": 1, "threshold": 1e3, "alpha": 1e-4}, np.random.default_rng(0))
    d = m.describe(fitted)
    assert d["term_count"] == 0 and d["constant_states"] == ["y"]
    assert any("thresholded away" in n and "not a divergence" in n for n in d["notes"])
    # ... and in the warnings the job copies into its notes
    assert d["warnings"] == ["every term of d(y)/dt was thresholded away (threshold 1000, relative): y is simulated "
                             "as its initial value held, a flat line; lower the threshold"]
    pred = m.predict(fitted, LINEAR.without_targets())
    assert not pred.diverged.any()
    for p, s in zip(pred, LINEAR.segments):
        assert np.ptp(p[:, 0]) == 0.0  # exactly flat
        assert p[0, 0] == pytest.approx(s.y0[0], rel=1e-12)  # at y0 (standardise / unstandardise round trip)
    # a model with terms lists no constant state
    fitted = m.fit(LINEAR, {"degree": 1, "threshold": 0.05, "alpha": 1e-4}, np.random.default_rng(0))
    assert m.describe(fitted)["constant_states"] == [] and m.describe(fitted)["warnings"] == []


# ----------------------------------------------------------------------------- (5) scale-free defaults
def _resampled(samples: Samples, dt: float) -> Samples:
    """The same sample arrays with another sample period (time = index x dt per segment)."""
    segs = tuple(replace(s, t=s.t[0] / DT * dt + np.arange(len(s.t)) * dt) for s in samples.segments)
    return replace(samples, segments=segs, dt=dt)


def test_relative_threshold_is_the_absolute_threshold_times_the_derivative_rms():
    """Two states with derivatives of very different sizes: the relative cut equals per-equation absolute cuts."""
    rel = SINDy(derivative="kalman", stlsq="pysindy")
    fit = rel.fit(QUADRATIC, {"degree": 3, "threshold": 0.2, "alpha": 1e-4}, RNG)
    rms = fit.derivative_rms[0]
    prep = rel._prepare(QUADRATIC)
    assert rms == pytest.approx(np.sqrt(np.mean(np.concatenate(prep.x_dot) ** 2)), rel=1e-12)
    # the unit is the rms unless STLSQ's first (ridge) pass has no coefficient that large
    z = np.hstack([np.vstack(prep.x), np.vstack(prep.u)])
    first = np.linalg.solve((t := library_features(z, fit.powers)).T @ t + 1e-4 * np.eye(t.shape[1]),
                            t.T @ np.concatenate(prep.x_dot))
    assert fit.threshold_unit[0] == pytest.approx(min(rms, np.abs(first).max()), rel=1e-8)
    absolute = SINDy(derivative="kalman", threshold_scale="absolute", stlsq="pysindy")
    ref = absolute.fit(QUADRATIC, {"degree": 3, "threshold": 0.2 * fit.threshold_unit[0], "alpha": 1e-4}, RNG)
    np.testing.assert_allclose(fit.coef, ref.coef, rtol=1e-9, atol=1e-12)
    d = rel.describe(fit)
    assert d["threshold_scale"] == "relative" and d["threshold_per_equation"] == [pytest.approx(0.2 * fit.threshold_unit[0])]
    # pysindy's own model object carries the same (rescaled) coefficients
    x, u = np.array([[0.3], [-1.0]]), np.array([[0.5], [0.1]])
    np.testing.assert_allclose(np.asarray(fit.model.predict(x, u=u)), library_features(np.hstack([x, u]), fit.powers)
                               @ fit.coef.T, rtol=1e-10, atol=1e-12)


def test_relative_thresholds_are_independent_of_the_sample_period():
    """The same samples read at 1 ms and at 10 s give the same model (in standardised units) and trajectories."""
    m = SINDy(derivative="kalman")
    params = {"degree": 2, "threshold": 0.1, "alpha": 1e-3}
    fast, slow = _resampled(LINEAR, 1e-3), _resampled(LINEAR, 10.0)
    a, b = m.fit(fast, params, RNG), m.fit(slow, params, RNG)
    np.testing.assert_array_equal(a.coef != 0, b.coef != 0)
    np.testing.assert_allclose(a.coef * 1e-3, b.coef * 10.0, rtol=1e-6, atol=1e-9)  # per second -> per sample
    for p, q in zip(m.predict(a, fast.without_targets()), m.predict(b, slow.without_targets())):
        np.testing.assert_allclose(p, q, rtol=1e-7, atol=1e-9)


def test_default_grid_keeps_terms_of_a_slow_system_that_absolute_thresholds_empty():
    """LINEAR's trajectories read as 150 samples of 100 s: dx/dt = (-2x + 3u) / 1000 s, standardised coefficients
    of a few 1e-3 per second. The seed's absolute grid (1e-2 .. 1e3) removes every term at every point; no point of
    the relative default grid does."""
    slow = _resampled(LINEAR, 100.0)
    rel, seed = SINDy(derivative="kalman", orders=(1,)), SINDy(derivative="kalman", threshold_scale="absolute", orders=(1,))
    grid_rel = grid_points(rel.search_space(slow))
    assert all(rel.describe(rel.fit(slow, p, RNG))["term_count"] >= 2 for p in grid_rel if p["degree"] == 1)
    assert all(rel.describe(rel.fit(slow, p, RNG))["constant_states"] == [] for p in grid_rel)
    assert all(seed.describe(seed.fit(slow, p, RNG))["term_count"] == 0
               for p in grid_points(seed.search_space(slow)) if p["degree"] == 1)
    # the relative model simulates the slow system exactly as well as the original one, and well
    rmse = []
    for data in (slow, LINEAR):
        fitted = rel.fit(data, {"degree": 1, "threshold": 0.1, "alpha": 1e-4}, RNG)
        rmse.append(np.sqrt(np.mean((np.concatenate(rel.predict(fitted, data.without_targets())) - data.y) ** 2)))
    assert rmse[0] == pytest.approx(rmse[1], rel=1e-6) and rmse[0] < 0.1 * np.std(slow.y)


# ----------------------------------------------------------------------------- (6) initialisation window
def _with_init(samples: Samples, n_init: int) -> Samples:
    """Evaluated view of whole segments with an initialisation window of ``n_init`` samples (as SamplePool builds)."""
    segs = []
    for s in samples.segments:
        segs.append(replace(s, rows=s.rows[n_init:], X=s.X[n_init:], y=s.y[n_init:], y_init=s.y[:n_init]))
    return replace(samples, segments=tuple(segs), init_samples=n_init)


def test_simulation_starts_from_the_last_sample_of_the_init_window():
    m = SINDy(derivative="kalman")
    fitted = m.fit(LINEAR, {"degree": 1, "threshold": 0.05, "alpha": 1e-4}, RNG)
    test = _samples(_linear, seed=11, durations=(6.0, 3.0))
    view = _with_init(test, 5).without_targets()
    preds = m.predict(fitted, view)
    assert [p.shape for p in preds] == [(len(s.t) - 5, 1) for s in test.segments]
    # the same as a segment that starts at row 4 with y0 = the measured y[4]
    for p, s in zip(preds, test.segments):
        tail = replace(s, U=s.U[4:], t=s.t[4:], rows=np.arange(1, len(s.t) - 4), y=None, y0=s.y[4], y_init=None)
        ref = m.predict(fitted, replace(test, segments=(tail,)))[0]
        np.testing.assert_array_equal(p, ref)
    # outputs after the window are never read; the window's last sample is
    seg = view.segments[0]
    moved = replace(seg, y_init=seg.y_init + np.r_[0, 0, 0, 0, 1.0][:, None])
    assert not np.allclose(m.predict(fitted, replace(view, segments=(moved,)))[0], preds[0])
    early = replace(seg, y_init=seg.y_init + np.r_[1.0, 1.0, 1.0, 1.0, 0][:, None], y0=seg.y0 + 1.0)
    np.testing.assert_array_equal(m.predict(fitted, replace(view, segments=(early,)))[0], preds[0])
    bad = replace(seg, y_init=seg.y_init * np.nan)
    with pytest.raises(MethodError, match=r"segment 's0' has no finite initial output y_init \(row 4\)"):
        m.predict(fitted, replace(view, segments=(bad,)))


def test_default_grid_keeps_a_term_where_the_library_explains_little():
    """An output the input does not drive (noise around a slow drift): the derivative's rms is large and every
    coefficient small, so a cut at 0.5 x rms would empty the model; the first-pass cap keeps its largest term."""
    rng = np.random.default_rng(4)
    frames = [pd.DataFrame({"segment": f"s{k}", "time": np.arange(200) * DT, "u": np.sin(0.05 * np.arange(200) + k),
                            "y": np.cumsum(rng.normal(size=200)) * 0.1 + rng.normal(size=200)}) for k in range(3)]
    data = make_samples(Dataset("noise", pd.concat(frames, ignore_index=True),
                                Schema.from_roles({"u": "input", "y": "output"}), DT), ["y"], "simulation")
    m = SINDy(derivative="kalman", orders=(1,))
    grid = grid_points(m.search_space(data))
    fits = [m.fit(data, p, RNG) for p in grid]
    assert all(m.describe(f)["term_count"] >= 1 for f in fits)
    top = [f for f, p in zip(fits, grid) if p["threshold"] == 0.5]
    assert all(f.threshold_unit[0] < 0.5 * f.derivative_rms[0] for f in top)  # capped well below the rms
    plain = SINDy(derivative="kalman", threshold_scale="absolute")  # the same cut at 0.5 x rms empties it
    rms = top[0].derivative_rms[0]
    assert plain.describe(plain.fit(data, {"degree": 1, "threshold": 0.5 * rms, "alpha": 1e-4}, RNG))["term_count"] == 0


def test_the_final_fit_reuses_the_grid_searchs_derivatives_and_equals_a_fresh_one(monkeypatch):
    """A job differentiates its training data once (the grid search), not again for the final fit:
    the prepared set is kept per process; a fit from it equals a fit computed afresh, and
    other data or another derivative setting is differentiated anew (``derivative_scale = "training"``)."""
    import enginebench.methods.sindy as sindy_module

    calls = []
    real = sindy_module.differentiate

    def counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(sindy_module, "differentiate", counting)
    sindy_module._prepared.clear()
    m = SINDy(derivative="kalman", derivative_scale="training", degrees=(1,), n_thresholds=2, n_alphas=1, orders=(1,))
    grid = grid_points(m.search_space(LINEAR))
    test = replace(LINEAR, segments=LINEAR.segments[:2]).without_targets()
    m.predict_grid(LINEAR, test, grid, RNG)
    per_training_set = len(calls)
    assert per_training_set == len(LINEAR.segments)  # one differentiation per segment
    kept = m.fit(LINEAR, grid[0], RNG)
    assert len(calls) == per_training_set  # the final fit reused them
    sindy_module._prepared.clear()
    fresh = m.fit(LINEAR, grid[0], RNG)
    assert len(calls) == 2 * per_training_set
    np.testing.assert_array_equal(kept.coef, fresh.coef)
    np.testing.assert_array_equal(np.concatenate(m.predict(kept, test)), np.concatenate(m.predict(fresh, test)))
    SINDy(derivative="kalman", derivative_scale="training", derivative_alpha=2.0, degrees=(1,)).fit(LINEAR, grid[0], RNG)
    m.fit(QUADRATIC, grid[0], RNG)
    assert len(calls) == 2 * per_training_set + len(LINEAR.segments) + len(QUADRATIC.segments)
    assert not m._prepare(LINEAR).x_dot[0].flags.writeable  # what a later fit reads cannot be changed


def test_segment_scaled_derivatives_are_computed_once_per_record_across_training_sets(monkeypatch):
    """With the default ``derivative_scale = "segment"`` a segment's derivative depends on the segment alone:
    k-fold training sets that share a record, and the final fit, differentiate it once; a second-order
    model's second derivatives are kept the same way. The fit equals one computed with an empty cache."""
    import enginebench.methods.sindy as sindy_module
    import enginebench.methods.sindy_grid as grid_module

    calls = []
    real = grid_module.differentiate

    def counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(grid_module, "differentiate", counting)
    monkeypatch.setattr(sindy_module, "differentiate", counting)
    sindy_module._prepared.clear()
    grid_module.clear_segment_cache()
    m = SINDy(derivative_chunk=128, derivative_margin=16)
    params = {"order": 2, "degree": 1, "threshold": 0.05, "alpha": 1e-4}
    folds = [replace(LINEAR, segments=tuple(LINEAR.segments[j] for j in keep)) for keep in ((0, 1), (1, 2), (0, 2))]
    fits = [m.fit(fold, params, RNG) for fold in folds]
    assert len(calls) == 2 * len(LINEAR.segments)  # each record's dy/dt and d2y/dt2 once, over three training sets
    final = m.fit(LINEAR, params, RNG)
    assert len(calls) == 2 * len(LINEAR.segments)
    sindy_module._prepared.clear()
    grid_module.clear_segment_cache()
    fresh = m.fit(LINEAR, params, RNG)
    np.testing.assert_array_equal(final.coef, fresh.coef)
    assert len({f.state_std[0] for f in fits}) == 3  # the training sets' standardisations do differ
    # the derivative in raw units does not depend on the training set it came with
    a, b = (m._prepare(f) for f in folds[:2])
    np.testing.assert_allclose(a.x_dot[1] * a.state_std, b.x_dot[0] * b.state_std, rtol=1e-12)


def test_tv_derivatives_are_solved_to_optimality_unless_the_lasso_solver_is_asked_for():
    """The default TV solver leaves no window unconverged and no note; the package's Lasso, capped, says so."""
    params = {"degree": 1, "threshold": 0.05, "alpha": 1e-4}
    exact = SINDy(derivative="trend_filtered", derivative_chunk=128, derivative_margin=16)
    d = exact.describe(exact.fit(LINEAR, params, np.random.default_rng(0)))
    assert not any("converge" in n for n in d["notes"])
    capped = SINDy(derivative="trend_filtered", derivative_chunk=128, derivative_margin=16,
                   derivative_solver="lasso", derivative_max_iter=5)
    notes = capped.describe(capped.fit(LINEAR, params, np.random.default_rng(0)))["notes"]
    n_windows = sum(len(window_bounds(len(s.t), 128, 16, 112)) for s in LINEAR.segments)
    assert f"differentiation: {n_windows} chunk(s) did not fully converge (derivative_max_iter)" in notes
    with pytest.raises(MethodError, match="option derivative_solver='cvx'; use 'admm' or 'lasso'"):
        SINDy(derivative_solver="cvx")


# ----------------------------------------------------------------------------- (7) second order, batched grid
OSC_DT = 0.05
ZETA, OMEGA, GAIN = 0.2, 2.0, 3.0


def _oscillator(seed: int, durations: tuple[float, ...] = (40.0, 40.0, 40.0)) -> Samples:
    """Segments of y'' = -2 zeta w y' - w^2 y + b u (zeta 0.2, w 2 rad/s, b 3) under a seeded smooth input."""
    rng = np.random.default_rng(seed)
    frames = []
    for k, dur in enumerate(durations):
        a, om, ph = rng.uniform(0.5, 1.5, 3), rng.uniform(0.2, 1.5, 3), rng.uniform(0, 2 * np.pi, 3)

        def u(t, a=a, om=om, ph=ph):
            return (a[:, None] * np.sin(om[:, None] * np.atleast_1d(t) + ph[:, None])).sum(axis=0)

        t = np.arange(0.0, dur, OSC_DT)
        sol = solve_ivp(lambda tt, s: [s[1], -2 * ZETA * OMEGA * s[1] - OMEGA**2 * s[0] + GAIN * u(tt)[0]],
                        (0.0, t[-1]), rng.uniform(-1, 1, 2), t_eval=t, rtol=1e-10, atol=1e-10)
        assert sol.success
        frames.append(pd.DataFrame({"segment": f"s{k}", "time": t + 1000.0 * k, "u": u(t), "y": sol.y[0]}))
    ds = Dataset("osc", pd.concat(frames, ignore_index=True), Schema.from_roles({"u": "input", "y": "output"}), OSC_DT)
    return make_samples(ds, ["y"], mode="simulation")


OSCILLATOR = _oscillator(5)


def _rmse(pred: np.ndarray, data: Samples) -> float:
    return float(np.sqrt(np.mean((pred.reshape(data.y.shape) - data.y) ** 2)))


def test_second_order_recovers_a_damped_oscillator_and_selection_prefers_it():
    """d2y/dt2 = Theta(y, y', u) xi identifies y'' = -0.8 y' - 4 y + 3 u to 1 % (default TV derivatives);
    its free run from a 20-sample init window (which gives y and dy/dt) tracks held-out data within 5 % of
    the output's deviation, where the best first-order model cannot oscillate and is several times worse,
    so selection on the free-run error (predict_grid) picks order 2."""
    m = SINDy()
    fitted = m.fit(OSCILLATOR, {"order": 2, "degree": 1, "threshold": 0.05, "alpha": 1e-4}, RNG)
    assert fitted.state_names == ("y", "y'") and fitted.order == 2
    names = ps.PolynomialLibrary(degree=1).fit(np.zeros((1, 3))).get_feature_names(["y", "y'", "u"])
    raw = raw_coefficients(fitted)
    kinematic, dynamic = dict(zip(names, raw[0])), dict(zip(names, raw[1]))
    assert kinematic["y'"] == pytest.approx(1.0, rel=1e-12) and abs(kinematic["1"]) < 1e-12
    assert kinematic["y"] == 0.0 and kinematic["u"] == 0.0
    assert dynamic["y"] == pytest.approx(-OMEGA**2, rel=1e-2)
    assert dynamic["y'"] == pytest.approx(-2 * ZETA * OMEGA, rel=1e-2)
    assert dynamic["u"] == pytest.approx(GAIN, rel=1e-2)
    assert abs(dynamic["1"]) < 0.01
    d = m.describe(fitted)
    assert d["order"] == 2 and d["term_count"] == 3 and d["constant_states"] == []
    assert d["equations_raw"][0] == "d(y)/dt = +1 y'" and d["equations_raw"][1].startswith("d(y')/dt = ")

    held_out = _with_init(_oscillator(6, durations=(30.0, 30.0)), 20)
    view = held_out.without_targets()
    second = _rmse(np.concatenate(m.predict(fitted, view)), held_out)
    assert second < 0.05 * np.std(held_out.y)  # (inputs held between samples)
    small = SINDy(degrees=(1, 2), n_thresholds=2, n_alphas=1)
    grid = grid_points(small.search_space(OSCILLATOR))
    out = small.predict_grid(OSCILLATOR, view, grid, RNG)
    scores = np.array([_rmse(o, held_out) for o in out])
    best_first = min(s for s, p in zip(scores, grid) if p["order"] == 1)
    assert best_first > 5 * second
    assert grid[int(np.nanargmin(scores))]["order"] == 2


def test_first_order_system_keeps_a_first_order_model():
    """On dx/dt = -2x + 3u the first-order model is recovered (as before) and wins selection over order 2."""
    m = SINDy(degrees=(1, 2), n_thresholds=2, n_alphas=1)
    fitted = m.fit(LINEAR, {"order": 1, "degree": 1, "threshold": 0.05, "alpha": 1e-4}, RNG)
    raw = _raw_terms(fitted)
    assert raw["y"] == pytest.approx(-2.0, rel=5e-3) and raw["u"] == pytest.approx(3.0, rel=5e-3)
    held_out = _with_init(_samples(_linear, seed=11, durations=(15.0, 15.0)), 5)
    grid = grid_points(m.search_space(LINEAR))
    out = m.predict_grid(LINEAR, held_out.without_targets(), grid, RNG)
    scores = np.array([_rmse(o, held_out) for o in out])
    assert grid[int(np.nanargmin(scores))]["order"] == 1
    assert scores[int(np.nanargmin(scores))] < 0.1 * np.std(held_out.y)  # (inputs held between samples)


@pytest.mark.parametrize("integrator", ["rk4", "euler"])
def test_candidates_in_one_loop_equal_one_by_one_simulate_batch(integrator):
    """simulate_candidates (every model x segment in one time loop) against the reference simulator, model by
    model, to 1e-9 relative: models of 1 and 2 states, degrees 1-3, one of them diverging (flagged alike)."""
    from enginebench.methods.sindy_grid import simulate_candidates

    rng = np.random.default_rng(3)
    lengths = (60, 45, 2, 80)
    us = [np.sin(np.linspace(0, 4, n))[:, None] * rng.uniform(0.5, 1.5) for n in lengths]
    ts = [np.arange(n) * 0.05 for n in lengths]
    for k in (1, 2):
        coefs, powers = [], []
        for degree in (1, 2, 3, 2, 1):
            p = ps.PolynomialLibrary(degree=degree).fit(np.zeros((1, k + 1))).powers_.astype(np.int64)
            c = rng.normal(scale=0.3, size=(k, p.shape[0]))
            c[:, 1:k + 1] -= 1.5 * np.eye(k)  # stable linear part
            coefs.append(c)
            powers.append(p)
        coefs[-1] = coefs[-1] + 4.0 * (powers[-1][:, :k].sum(axis=1) == 1)  # unstable: leaves the envelope
        x0 = rng.uniform(-0.5, 0.5, (len(lengths), k))
        lo, hi = -3 * np.ones(k), 3 * np.ones(k)
        traj, n, div = simulate_candidates(coefs, powers, x0, us, ts, lo, hi, integrator=integrator, substeps=2)
        assert div[-1].any() and not div[0].any()
        for c in range(len(coefs)):
            ref, ref_div = simulate_batch(coefs[c], powers[c], x0, us, ts, lo, hi, integrator=integrator, substeps=2)
            np.testing.assert_array_equal(div[c], ref_div)
            for s, r in enumerate(ref):
                np.testing.assert_allclose(traj[c, s, : n[s]], r, rtol=1e-9, atol=1e-12)


def test_second_order_checks_and_errors():
    from enginebench.testing import check_method

    report = check_method(SINDy, {"derivative": "kalman", "orders": (2,), "degrees": (1,), "n_thresholds": 1,
                                  "n_alphas": 1})
    assert "determinism[simulation]" in report.passed and "no-target-leakage[simulation]" in report.passed
    with pytest.raises(MethodError, match=r"orders must list model orders from 1 \(dy/dt\) and 2"):
        SINDy(orders=(3,))
    with pytest.raises(MethodError, match=r"parameter order must be 1 \(dy/dt\) or 2"):
        SINDy().fit(LINEAR, {"order": 3}, RNG)


@pytest.mark.parametrize("name", ["linear", "quadratic", "oscillator"])
def test_stlsq_from_the_gram_matrix_equals_pysindys(name):
    """The default STLSQ (normal equations formed once per order and degree) gives pysindy's models over a grid:
    the same terms kept and coefficients to 1e-4 relative (the Gram matrix squares the library's condition
    number: on a first-order system the second-order state is nearly collinear with (y, u) and degree-3 fits
    differ from pysindy's by up to about 1e-5), both orders."""
    data = {"linear": LINEAR, "quadratic": QUADRATIC, "oscillator": OSCILLATOR}[name]
    gram, ref = SINDy(derivative="kalman"), SINDy(derivative="kalman", stlsq="pysindy")
    for p in grid_points(gram.search_space(data)):
        a, b = gram.fit(data, p, RNG), ref.fit(data, p, RNG)
        np.testing.assert_array_equal(a.coef != 0, b.coef != 0)
        np.testing.assert_allclose(a.coef, b.coef, rtol=1e-4, atol=1e-10 * np.abs(b.coef).max())
        assert gram.describe(a)["equations_raw"] == ref.describe(b)["equations_raw"]


def test_a_relative_threshold_and_alpha_declare_the_bounds_their_grids_are_extended_to():
    from enginebench.methods.sindy import ALPHA_BOUND, RELATIVE_THRESHOLD_BOUND, SINDy

    relative = SINDy().search_bounds(None)
    assert relative["threshold"] == RELATIVE_THRESHOLD_BOUND == (1e-4, 1.0) and relative["alpha"] == ALPHA_BOUND
    absolute = SINDy(threshold_scale="absolute").search_bounds(None)
    assert "threshold" not in absolute and absolute["alpha"] == ALPHA_BOUND  # in the ODE's units: no bound
