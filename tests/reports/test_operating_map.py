"""The operating map bins a synthetic map with a known error pattern back exactly."""

from __future__ import annotations

import numpy as np

from enginebench.reports.operating_map import operating_map


def test_a_known_error_pattern_comes_back_bin_by_bin():
    rng = np.random.default_rng(0)
    speed, load = rng.uniform(0, 4, 20_000), rng.uniform(0, 2, 20_000)
    truth = rng.normal(size=speed.size)
    # method "a" errs by exactly (1 + bin_x) in bin (bin_y, bin_x), sign alternating: its bin RMSE is 1 + bin_x
    bx, by = np.minimum((speed).astype(int), 3), np.minimum((load).astype(int), 1)
    sign = np.where(np.arange(speed.size) % 2, 1.0, -1.0)
    preds = {"a": truth + sign * (1.0 + bx), "b": truth.copy()}
    train_speed, train_load = np.r_[0.0, rng.uniform(0, 2, 500), 4.0], np.r_[0.0, rng.uniform(0, 2, 500), 2.0]
    m = operating_map(speed, load, truth, preds, train_speed, train_load, names=("speed", "load"), bins=4)
    np.testing.assert_allclose(m.x_edges, [0, 1, 2, 3, 4])
    np.testing.assert_allclose(m.y_edges, [0, 0.5, 1, 1.5, 2])
    for j in range(4):
        expected = 1.0 + j
        np.testing.assert_allclose(m.rmse["a"][:, j], expected, rtol=1e-12)
    np.testing.assert_array_equal(m.rmse["b"], np.zeros((4, 4)))
    assert m.rows.sum() == speed.size
    np.testing.assert_array_equal(m.rows, np.histogram2d(load, speed, bins=[m.y_edges, m.x_edges])[0])
    # training rows lie at speed < 2 except the two corner points: bins at speed 2..3 hold test rows only
    assert m.extrapolated[:, 2].all() and not m.extrapolated[:, 0].any()


def test_bins_without_evaluated_rows_are_nan():
    m = operating_map([0.0, 0.1], [0.0, 0.1], [1.0, 2.0], {"a": [1.5, 2.5]}, [0.0, 1.0], [0.0, 1.0], bins=3)
    assert np.isnan(m.rmse["a"][2, 2]) and m.rmse["a"][0, 0] == 0.5
