"""The ``arx`` baseline: exact coefficient recovery, free run equal to scipy's lfilter, the init window,
divergence flags, the derived order grid, describe's poles and conformance."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.signal

from enginebench.errors import MethodError
from enginebench.method import SegmentPredictions, grid_points
from enginebench.methods.arx import ARX, ARXFit, simulate
from enginebench.methods.freerun import Envelope
from helpers import A_TRUE, B1_TRUE, B2_TRUE, OFFSET, linear_raw, sim_samples

PARAMS = {"na": 2, "nb": 2, "nk": 1}


@pytest.fixture(scope="module")
def fitted() -> ARXFit:
    return ARX().fit(sim_samples(linear_raw()), PARAMS, np.random.default_rng(0))


def test_recovers_the_coefficients_of_a_noise_free_linear_system(fitted):
    np.testing.assert_allclose(fitted.a[0], -A_TRUE[1:], atol=1e-10)
    np.testing.assert_allclose(fitted.b[0, 0], B1_TRUE[1:], atol=1e-10)
    np.testing.assert_allclose(fitted.b[0, 1], B2_TRUE[1:], atol=1e-10)
    np.testing.assert_allclose(fitted.c, [OFFSET], atol=1e-10)


def test_higher_orders_and_no_delay_find_zero_extra_coefficients():
    fit = ARX().fit(sim_samples(linear_raw()), {"na": 4, "nb": 4, "nk": 0}, np.random.default_rng(0))
    # the true model lies inside the larger structure (its coefficients are not unique): check the free run
    raw = linear_raw(1, 200, seed=5)
    traj = sim_samples(raw).segments[0]
    pred = ARX().predict(fit, sim_samples(raw, init_samples=8).without_targets())
    np.testing.assert_allclose(pred[0], traj.y[8:], atol=1e-8)


def test_free_run_equals_lfilter_after_the_init_window(fitted):
    raw = linear_raw(2, 500, seed=3)
    data = sim_samples(raw, init_samples=20)
    pred = ARX().predict(fitted, data.without_targets())
    assert isinstance(pred, SegmentPredictions) and not pred.diverged.any()
    for seg, p in zip(raw.segments, pred):
        u1, u2 = seg.U[:, 0], seg.U[:, 1]
        ref = scipy.signal.lfilter(B1_TRUE, A_TRUE, u1) + scipy.signal.lfilter(B2_TRUE, A_TRUE, u2) \
            + scipy.signal.lfilter([OFFSET], A_TRUE, np.ones(len(u1)))
        np.testing.assert_allclose(p[:, 0], ref[20:], rtol=0, atol=1e-9)


def _recursion(a, b, c, nk, U, window):
    """The ARX recursion written out, edge padding before row 0 and the window shorter than na."""
    n, N = len(U), len(window)
    y = np.empty(n)
    y[:N] = window
    for t in range(N, n):
        acc = c
        for i, ai in enumerate(a, start=1):
            acc += ai * y[max(t - i, 0)]
        for j in range(U.shape[1]):
            for lag in range(b.shape[1]):
                acc += b[j, lag] * U[max(t - nk - lag, 0), j]
        y[t] = acc
    return y


@pytest.mark.parametrize("window_len, nk", [(1, 0), (2, 1), (7, 2)])
def test_simulate_is_exactly_the_recursion(window_len, nk):
    rng = np.random.default_rng(window_len)
    a = np.array([0.5, -0.2, 0.1, 0.05])                # na = 4 > window of 1 or 2: padded with the first value
    b = rng.normal(size=(2, 3))
    U = rng.normal(size=(60, 2))
    window = rng.normal(size=window_len)
    np.testing.assert_allclose(simulate(a, b, 0.3, nk, U, window), _recursion(a, b, 0.3, nk, U, window),
                               rtol=1e-12, atol=1e-12)


def test_without_a_window_the_run_starts_from_y0(fitted):
    data = sim_samples(linear_raw(1, 100, seed=4))
    seg = data.segments[0]
    pred = ARX().predict(fitted, data.without_targets())[0][:, 0]
    assert pred[0] == seg.y0[0]
    a, b = fitted.a[0], fitted.b[0]
    np.testing.assert_allclose(pred, _recursion(a, b, fitted.c[0], 1, seg.U, seg.y0), atol=1e-12)


def test_only_the_init_window_is_read(fitted):
    data = sim_samples(linear_raw(2, 200, seed=6), init_samples=10).without_targets()
    before = ARX().predict(fitted, data)
    seg = data.segments[0]
    changed = replace(data, segments=(replace(seg, y=np.full((len(seg), 1), 99.0)), *data.segments[1:]))
    np.testing.assert_array_equal(np.concatenate(ARX().predict(fitted, changed)), np.concatenate(before))
    moved = replace(data, segments=(replace(seg, y_init=seg.y_init + 1.0), *data.segments[1:]))
    after = ARX().predict(fitted, moved)
    assert not np.allclose(after[0], before[0])
    np.testing.assert_array_equal(after[1], before[1])


def test_an_unstable_run_is_held_and_flagged():
    fit = ARXFit(na=1, nb=1, nk=0, a=np.array([[1.2]]), b=np.zeros((1, 2, 1)), c=np.zeros(1),
                 input_names=("u1", "u2"), target_names=("y",), envelope=Envelope(np.array([-5.0]), np.array([5.0])),
                 n_rows=10)
    data = sim_samples(linear_raw(2, 400, seed=1), init_samples=3).without_targets()
    data = replace(data, segments=(replace(data.segments[0], y_init=np.ones((3, 1))),
                                   replace(data.segments[1], y_init=np.zeros((3, 1)))))
    pred = ARX().predict(fit, data)
    assert pred.diverged.tolist() == [True, False]
    assert np.isfinite(pred[0]).all() and np.abs(pred[0]).max() <= 5.0
    assert pred[0][-1, 0] == pytest.approx(1.2 ** 8)  # 1.2^8 = 4.3 is the last value inside [-5, 5]
    np.testing.assert_array_equal(pred[1], 0.0)


def test_describe_gives_polynomials_poles_and_stability(fitted):
    d = ARX().describe(fitted)
    y = d["targets"]["y"]
    assert y["A(q)"] == "1 - 1.5 q^-1 + 0.7 q^-2"
    assert y["B(q)"]["u1"] == "q^-1 (0.5 + 0.3 q^-1)"
    assert sorted(p[1] for p in y["poles"]) == pytest.approx([-np.sqrt(0.7 - 0.5625), np.sqrt(0.7 - 0.5625)])
    assert y["max_pole_modulus"] == pytest.approx(np.sqrt(0.7)) and y["stable"] and d["stable"]
    assert y["static_gain"]["u1"] == pytest.approx(0.8 / 0.2)


def test_predict_grid_is_fit_then_predict_for_every_point():
    m = ARX()
    train, test = sim_samples(linear_raw(2, 200, seed=8)), sim_samples(linear_raw(1, 150, seed=9), 5)
    grid = grid_points({"na": np.array([1, 2]), "nb": np.array([1, 3]), "nk": np.array([0, 1])})
    out = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    for i, p in enumerate(grid):
        one = np.concatenate(m.predict(m.fit(train, p, np.random.default_rng(0)), test.without_targets()))
        # the grid reads every point from one Gram matrix of its longest lags: the same sums, another order
        np.testing.assert_allclose(out[i], one, rtol=1e-12, atol=1e-12)


def test_order_grid_is_derived_from_the_training_data():
    big = sim_samples(linear_raw(3, 300))
    # 300-row segments: o <= 75 and 3 o + 1 <= 90 parameters keep 1 .. 16 of the base orders
    space = ARX().search_space(big)
    assert space["order"].tolist() == [1, 2, 4, 8, 16] and space["nk"].tolist() == [0, 1] and "na" not in space
    small = sim_samples(linear_raw(3, 30))  # o <= 7 and 3 o + 1 <= 9: orders 1 and 2
    assert ARX().search_space(small)["order"].tolist() == [1, 2]
    assert ARX(max_order=4).search_space(big)["order"].tolist() == [1, 2, 4]
    fixed = ARX(na=3, nb=[2, 5], nk=1).search_space(big)
    assert [fixed[k].tolist() for k in ("na", "nb", "nk")] == [[3], [2, 5], [1]]
    one = ARX(na=2).search_space(big)
    assert one["na"].tolist() == [2] and one["nb"].tolist() == [1, 2, 4, 8, 16]


def test_a_tied_order_is_na_equal_nb(fitted):
    train = sim_samples(linear_raw())
    tied = ARX().fit(train, {"order": 2, "nk": 1}, np.random.default_rng(0))
    np.testing.assert_array_equal(tied.a, fitted.a)
    np.testing.assert_array_equal(tied.b, fitted.b)


@pytest.mark.parametrize("options, fragment", [
    ({"nb": 0}, "option nb=0 must be >= 1"),
    ({"na": -1}, "option na=-1 must be a whole number of samples >= 0"),
    ({"na": 1.5}, "option na=1.5 must be a whole number"),
    ({"envelope": 0}, "option envelope must be a positive number"),
])
def test_bad_options_are_one_line(options, fragment):
    with pytest.raises(MethodError, match=fragment):
        ARX(**options)


def test_orders_beyond_the_data_are_refused():
    with pytest.raises(MethodError, match=r"orders na=16, nb=16, nk=1 leave 0 regression rows .* use lower orders"):
        ARX().fit(sim_samples(linear_raw(2, 12)), {"na": 16, "nb": 16, "nk": 1}, np.random.default_rng(0))


def test_bad_prediction_input_is_one_line(fitted):
    data = sim_samples(linear_raw(1, 50), 5).without_targets()
    narrow = data.select_features([0])
    with pytest.raises(MethodError, match="has 1 feature columns but the model was fitted on 2 inputs"):
        ARX().predict(fitted, narrow)
    seg = data.segments[0]
    U = seg.U.copy()
    U[7, 1] = np.nan
    with pytest.raises(MethodError, match=r"segment 's0' has nan/inf in input column 1 at row 7"):
        ARX().predict(fitted, replace(data, segments=(replace(seg, U=U),)))


def test_selection_skips_orders_the_fitting_pieces_cannot_carry():
    train, test = sim_samples(linear_raw(2, 12)), sim_samples(linear_raw(1, 50, seed=2), 5)
    grid = [{"na": 16, "nb": 16, "nk": 1}, {"na": 1, "nb": 1, "nk": 1}]
    out = ARX().predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()
