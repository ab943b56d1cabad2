"""``poly-narx``: a known polynomial system's coefficients recovered (one step ahead and by the simulation-error
refinement), the refinement's gradient against finite differences, the batched free run against a loop written
out, grid predictions against single fits, the refusal of lags the data cannot carry, and conformance."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import RawSegments
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.method import grid_points
from enginebench.methods.freerun import Trajectory
from enginebench.methods.poly_narx import (PolyNARX, features, lag_rows, least_squares, refine, section_error,
                                           sections, select_monomials, term_names, term_table)
from enginebench.testing import check_method
from helpers import sim_samples

# y(t) = 0.1 + 1.2 y(t-1) - 0.5 y(t-2) + 0.4 u(t) + 0.2 u(t-1) + 0.05 y(t-1)^2 - 0.1 y(t-1)^3 + 0.03 y(t-1) y(t-2)^2
TRUE = {"1": 0.1, "y(t-1)": 1.2, "y(t-2)": -0.5, "u(t-0)": 0.4, "u(t-1)": 0.2, "y(t-1)^2": 0.05,
        "y(t-1)^3": -0.1, "y(t-1)*y(t-2)^2": 0.03}
PARAMS = {"lags": 2, "nk": 0, "nonlinear_lags": 2}


def system(u: np.ndarray, y0: float = 0.0, y1: float = 0.0) -> np.ndarray:
    """The true system's recursion from rest (y(-1) = y0, y(-2) = y1, u(-1) = u(0))."""
    y = np.empty(len(u))
    p1, p2, up = y0, y1, u[0]
    for t in range(len(u)):
        y[t] = (TRUE["1"] + TRUE["y(t-1)"] * p1 + TRUE["y(t-2)"] * p2 + TRUE["u(t-0)"] * u[t] + TRUE["u(t-1)"] * up
                + TRUE["y(t-1)^2"] * p1 ** 2 + TRUE["y(t-1)^3"] * p1 ** 3 + TRUE["y(t-1)*y(t-2)^2"] * p1 * p2 ** 2)
        p2, p1, up = p1, y[t], u[t]
    return y


def poly_raw(n_seg: int = 2, n: int = 600, seed: int = 0) -> RawSegments:
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n_seg):
        u = rng.uniform(-1.0, 1.0, n)
        frames.append(pd.DataFrame({"segment": f"s{k}", "time": np.arange(n) + 1000.0 * k, "u": u, "y": system(u)}))
    ds = Dataset("poly", pd.concat(frames, ignore_index=True), Schema.from_roles({"u": "input", "y": "output"}), 1.0)
    return RawSegments.from_dataset(ds)


def _raw_trajectories(seed: int = 0) -> list[Trajectory]:
    raw = poly_raw(seed=seed)
    return [Trajectory(s.id, np.asarray(s.U, float), np.asarray(s.y, float).reshape(-1, 1))
            for s in sim_samples(raw).segments]


def _true_theta(table: np.ndarray) -> np.ndarray:
    names = term_names(table, 2, 2, 0, ["u"], "y")
    return np.array([TRUE.get(n, 0.0) for n in names])


def test_the_system_is_stable_and_nonlinear():
    y = sim_samples(poly_raw()).segments[0].y
    assert np.isfinite(y).all() and 0.3 < np.ptp(y) < 10
    assert abs(TRUE["y(t-1)^3"]) * np.abs(y).max() ** 3 > 0.05  # the cubic term matters over the record


def test_equation_error_least_squares_recovers_the_coefficients():
    traj = _raw_trajectories()
    table = term_table(2, 2, 1, 2, 3)
    Z, y = lag_rows(traj, 0, 2, 2, 0)
    theta = least_squares(features(Z, table), y)
    np.testing.assert_allclose(theta, _true_theta(table), atol=1e-9)


def test_the_refinement_returns_to_the_coefficients_from_a_perturbed_start():
    traj = _raw_trajectories()
    table = term_table(2, 2, 1, 2, 3)
    truth = _true_theta(table)
    start = truth + 0.01 * np.random.default_rng(1).standard_normal(len(truth))
    sec = sections(traj, 0, 2, 2, 0, 50)
    theta, before, after, iterations = refine(start, table, 2, sec, max_iter=50, tol=1e-14)
    assert iterations > 0 and after < 1e-16 * before + 1e-20
    np.testing.assert_allclose(theta, truth, atol=1e-7)


def test_the_sections_gradient_equals_finite_differences():
    traj = _raw_trajectories(seed=3)
    table = term_table(2, 2, 1, 2, 3)
    theta = _true_theta(table) + 0.02 * np.random.default_rng(2).standard_normal(len(table))
    sec = sections(traj, 0, 2, 2, 0, 40)
    cost, _, JTr = section_error(theta, table, 2, sec, gradient=True)
    numeric = np.empty(len(theta))
    for i in range(len(theta)):
        h = 1e-6 * max(1.0, abs(theta[i]))
        up, dn = theta.copy(), theta.copy()
        up[i] += h
        dn[i] -= h
        numeric[i] = (section_error(up, table, 2, sec, False)[0] - section_error(dn, table, 2, sec, False)[0]) / (2 * h)
    np.testing.assert_allclose(2 * JTr, numeric, rtol=1e-5, atol=1e-8 * abs(cost))


def test_sections_cover_every_sample_once_or_more_and_start_from_measured_lags():
    traj = _raw_trajectories()
    sec = sections(traj, 0, 2, 2, 0, 70)  # 598 simulated steps per segment: 8 full sections and one at the end
    assert sec.y.shape == (2 * 9, 72) and sec.z_u.shape == (18, 70, 2)
    np.testing.assert_array_equal(sec.y[0], traj[0].Y[:72, 0])
    np.testing.assert_array_equal(sec.y[8], traj[0].Y[-72:, 0])
    np.testing.assert_array_equal(sec.z_u[0, 0], [traj[0].U[2, 0], traj[0].U[1, 0]])


def test_the_fitted_method_reproduces_a_fresh_free_run():
    method = PolyNARX()
    fitted = method.fit(sim_samples(poly_raw()), PARAMS, np.random.default_rng(0))
    fresh = poly_raw(1, 400, seed=7)
    truth = sim_samples(fresh).segments[0].y[:, 0]
    pred = method.predict(fitted, sim_samples(fresh, init_samples=10).without_targets())
    assert not pred.diverged.any()
    np.testing.assert_allclose(pred[0][:, 0], truth[10:], atol=1e-7)
    assert fitted.models[0].error < 1e-6
    terms = method.describe(fitted)["targets"]["y"]["terms"]
    assert "y(t-1)^3" in terms and "y(t-1)*y(t-2)^2" in terms


def _reference_run(method: PolyNARX, fitted, u: np.ndarray, window: np.ndarray) -> np.ndarray:
    """The fitted model's recursion written out term by term in measured units (edge padding before row 0)."""
    m = fitted.models[0]
    us = (u - fitted.u_mean[0]) / fitted.u_std[0]
    ys = np.empty(len(u))
    ys[:len(window)] = (window - fitted.y_mean[0]) / fitted.y_std[0]
    for t in range(len(window), len(u)):
        z = [ys[max(t - i, 0)] if t - i >= 0 else ys[0] for i in range(1, m.na + 1)]
        z += [us[max(t - m.nk - lag, 0)] for lag in range(m.nb)] + [1.0]
        ys[t] = sum(th * np.prod([z[v] for v in row]) for th, row in zip(m.theta, m.terms))
    return ys * fitted.y_std[0] + fitted.y_mean[0]


@pytest.mark.parametrize("params", [PARAMS, {"lags": 4, "nk": 1, "nonlinear_lags": 1}])
def test_free_run_equals_a_loop_written_out(params):
    method = PolyNARX(refine=False)
    raw = poly_raw(seed=2)
    fitted = method.fit(sim_samples(raw), params, np.random.default_rng(0))
    test = poly_raw(2, 300, seed=9)
    data = sim_samples(test, init_samples=3).without_targets()
    pred = method.predict(fitted, data)
    for seg, p in zip(sim_samples(test).segments, pred):
        ref = _reference_run(method, fitted, np.asarray(seg.U[:, 0], float), seg.y[:3, 0])
        np.testing.assert_allclose(p[:, 0], ref[3:], rtol=1e-10, atol=1e-10)


def test_grid_predictions_equal_each_points_own_fit_and_free_run():
    method = PolyNARX(max_iter=5)
    train = sim_samples(poly_raw(seed=4))
    data = sim_samples(poly_raw(2, 250, seed=5), init_samples=6).without_targets()
    grid = grid_points({"lags": np.array([2, 4]), "nk": np.array([0, 1]), "nonlinear_lags": np.array([1, 4])})
    batched = method.predict_grid(train, data, grid, np.random.default_rng(0))
    for i, params in enumerate(grid):
        own = np.concatenate(method.predict(method.fit(train, params, np.random.default_rng(0)), data))
        np.testing.assert_allclose(batched[i], own, rtol=1e-12, atol=1e-12)


def test_nonlinear_lags_above_the_output_lags_are_the_output_lags():
    assert PolyNARX._point({"lags": 2, "nk": 0, "nonlinear_lags": 4}) == (2, 2, 0, 2)
    with pytest.raises(MethodError, match="unknown hyperparameter"):
        PolyNARX._point({"lags": 2, "nk": 0, "nonlinear_lags": 1, "gamma": 1.0})


def test_lags_the_training_data_cannot_carry_are_refused_with_the_counts():
    train = sim_samples(poly_raw(1, 40))
    with pytest.raises(MethodError, match=r"leave \d+ regression rows for \d+ coefficients"):
        PolyNARX().fit(train, {"lags": 16, "nk": 0, "nonlinear_lags": 4}, np.random.default_rng(0))


def test_divergent_runs_are_held_and_flagged():
    method = PolyNARX(refine=False)
    fitted = method.fit(sim_samples(poly_raw()), PARAMS, np.random.default_rng(0))
    m = fitted.models[0]
    theta = m.theta.copy()
    theta[1] = 3.0  # y(t-1) coefficient: explosive
    from dataclasses import replace

    bad = replace(fitted, models=(replace(m, theta=theta),))
    pred = method.predict(bad, sim_samples(poly_raw(1, 200, seed=8), init_samples=5).without_targets())
    assert pred.diverged.all() and np.isfinite(pred[0]).all()
    assert (pred[0] <= fitted.envelope.upper).all() and (pred[0] >= fitted.envelope.lower).all()


def test_passes_check_method_in_simulation_mode():
    check_method(PolyNARX, mode="simulation")


def test_row_and_section_caps_keep_rows_spread_evenly_and_built_alone():
    from enginebench.methods.freerun import Trajectory
    from enginebench.methods.poly_narx import lag_rows, sections, spread

    rng = np.random.default_rng(5)
    traj = [Trajectory(f"s{i}", rng.normal(size=(n, 2)), rng.normal(size=(n, 1))) for i, n in enumerate((300, 2, 250))]
    Z, y = lag_rows(traj, 0, 3, 2, 1)
    keep = spread(len(y), 40)
    assert len(keep) == 40 and keep[0] == 0 and keep[-1] == len(y) - 1
    Zc, yc = lag_rows(traj, 0, 3, 2, 1, max_rows=40)
    assert Zc.tobytes() == Z[keep].tobytes() and yc.tobytes() == y[keep].tobytes()
    assert lag_rows(traj, 0, 3, 2, 1, max_rows=len(y))[0].tobytes() == Z.tobytes()  # at or below the cap: all rows
    full = sections(traj, 0, 3, 2, 1, horizon=20)
    capped = sections(traj, 0, 3, 2, 1, horizon=20, max_sections=5)
    sel = spread(len(full.y), 5)
    assert capped.y.tobytes() == full.y[sel].tobytes() and capped.z_u.tobytes() == full.z_u[sel].tobytes()


def _greedy_reference(Phi: np.ndarray, y: np.ndarray, always: np.ndarray, penalty: float) -> np.ndarray:
    """Forward selection written out with a least-squares refit per candidate, then the criterion's minimum."""
    n = len(y)
    kept = list(np.flatnonzero(always))
    left = list(np.flatnonzero(~always))

    def rss(cols: list) -> float:
        theta, *_ = np.linalg.lstsq(Phi[:, cols], y, rcond=None)
        r = y - Phi[:, cols] @ theta
        return float(r @ r)

    path = [rss(kept)]
    order = []
    while left:
        best = min(left, key=lambda c: rss(kept + order + [c]))
        order.append(best)
        left.remove(best)
        path.append(rss(kept + order))
    crit = n * np.log(np.array(path) / n) + penalty * (len(kept) + np.arange(len(path)))
    keep = always.copy()
    keep[order[:int(np.argmin(crit))]] = True
    return keep


@pytest.mark.parametrize("rule", ["aic", "bic"])
def test_forward_selection_of_monomials_equals_a_refit_per_candidate_reference(rule):
    rng = np.random.default_rng(4)
    n = 1500
    Phi = np.column_stack([np.ones(n), rng.standard_normal((n, 3)), rng.standard_normal((n, 8)) ** 2])
    always = np.arange(12) < 4
    y = Phi[:, :4] @ [0.3, 1.0, -0.5, 0.2] + 0.4 * Phi[:, 6] - 0.25 * Phi[:, 9] + 0.1 * rng.standard_normal(n)
    keep = select_monomials(Phi, y, always, rule)
    np.testing.assert_array_equal(keep, _greedy_reference(Phi, y, always, np.log(n) if rule == "bic" else 2.0))
    assert keep[6] and keep[9] and keep[:4].all()
    if rule == "bic":  # no candidate without a true coefficient passes BIC's penalty here
        np.testing.assert_array_equal(np.flatnonzero(keep), [0, 1, 2, 3, 6, 9])
    assert select_monomials(Phi, y, always, "all").all()


def test_terms_all_keeps_every_monomial_and_aic_the_true_ones():
    raw = poly_raw()
    every = PolyNARX(terms="all").fit(sim_samples(raw), PARAMS, np.random.default_rng(0))
    chosen = PolyNARX().fit(sim_samples(raw), PARAMS, np.random.default_rng(0))
    assert len(every.models[0].theta) == len(term_table(2, 2, 1, 2, 3))
    names = set(PolyNARX().describe(chosen)["targets"]["y"]["terms"])
    assert {"y(t-1)^2", "y(t-1)^3", "y(t-1)*y(t-2)^2"} <= names
