"""Model selection: resampling units, the validation scheme, and trajectory-preserving subsamples."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.datasets.pools import make_samples
from enginebench.errors import MethodError
from enginebench.experiments.jobs import subsample, subsample_segments
from enginebench.experiments.selection import resample_pairs, select
from enginebench.experiments.spec import Selection
from enginebench.methods.krls import KRLS
from enginebench.results.metrics import grid_scores


def test_segment_bootstrap_keeps_trajectories_whole():
    sizes = np.array([5, 7, 3, 9])
    edges = np.r_[0, np.cumsum(sizes)]
    pairs = resample_pairs(int(sizes.sum()), Selection(resamples=4), np.random.default_rng(2), sizes)
    assert pairs
    for fit, val in pairs:
        for rows in (fit, val):
            seg = np.searchsorted(edges, rows, side="right") - 1
            for k in np.unique(seg):  # every used segment is used whole
                count = np.sum(seg == k)
                assert count % sizes[k] == 0
        assert not set(val) & set(fit)


def test_segment_kfold_is_blocked_by_segment():
    sizes = np.array([2, 2, 2, 2])
    pairs = resample_pairs(8, Selection(kind="kfold", folds=2), np.random.default_rng(0), sizes)
    assert [list(v) for _, v in pairs] == [[0, 1, 2, 3], [4, 5, 6, 7]]


def test_subsample_segments_reaches_the_size_with_whole_segments():
    sizes = np.array([10, 10, 10, 10, 10])
    rows = subsample_segments(sizes, 25, np.random.default_rng(0))
    assert len(rows) == 30 and len(np.unique(rows // 10)) == 3
    assert np.array_equal(subsample_segments(sizes, 0, np.random.default_rng(0)), np.arange(50))
    assert np.array_equal(subsample(50, 0, np.random.default_rng(0)), np.arange(50))


def test_validation_scheme_scores_on_the_validation_part(toy):
    train = make_samples(toy.select_segments(["s0", "s1"]), ["y"])
    val = make_samples(toy.select_segments(["s2"]), ["y"])
    method = KRLS(gamma_grid=(-2, 0, 3), lambda_grid=(-3, -1, 3))
    params, record = select(method, train, Selection(kind="validation"), np.random.default_rng(0), val)
    from enginebench.method import grid_points

    grid = grid_points(method.search_space(train))
    scores = grid_scores(method.predict_grid(train, val.without_targets(), grid, np.random.default_rng(0)), val, "mae")
    assert params == grid[int(np.argmin(scores))]
    assert record["best_score"] == pytest.approx(scores.min())
    with pytest.raises(MethodError, match="selection kind 'validation' needs a split with a validation part"):
        select(method, train, Selection(kind="validation"), np.random.default_rng(0), None)


def test_rmae_criterion_averages_segments(toy):
    data = make_samples(toy.select_segments(["s0", "s1"]), ["y"])
    n0 = len(data.segments[0])
    preds = data.y[None].copy()
    preds[0, :n0] += 1.0  # error 1 on the first segment, 0 on the second
    assert grid_scores(preds, data, "rmae")[0] == pytest.approx(0.5)
    assert grid_scores(preds, data, "mae")[0] == pytest.approx(n0 / len(data))


# ----------------------------------------------------------------------------- the selection table
def test_the_selection_table_equals_a_refit_of_every_point_on_every_resample(toy):
    """Each stored score is the MAE of that point fitted on that resample's rows alone (fit + predict, not predict_grid)."""
    from enginebench.method import grid_points

    train = make_samples(toy.select_segments(["s0", "s1", "s2"]), ["y"]).take(np.arange(0, 360, 3))
    method = KRLS(gamma_grid=(-2, 0, 3), lambda_grid=(-3, -1, 3))
    selection = Selection(kind="bootstrap", resamples=3)
    params, record = select(method, train, selection, np.random.default_rng(4))
    table = record["table"].frame()
    grid = grid_points(method.search_space(train))
    pairs = resample_pairs(len(train), selection, np.random.default_rng(4))  # the same draws, made again
    assert len(pairs) == 3 and len(table) == 9 * 3
    for j, (fit_rows, val_rows) in enumerate(pairs):
        fit_part, val_part = train.take(fit_rows), train.take(val_rows)
        for k, point in enumerate(grid):
            fitted = method.fit(fit_part, point, np.random.default_rng(0))
            guess = np.concatenate(method.predict(fitted, val_part.without_targets()))
            row = table[(table["point"] == k) & (table["resample"] == j)]
            assert len(row) == 1
            assert row["score"].iloc[0] == pytest.approx(np.mean(np.abs(guess - val_part.y)), rel=1e-6)
            assert row["param:gamma"].iloc[0] == point["gamma"] and row["param:lambda"].iloc[0] == point["lambda"]
    mean = table.groupby("point")["score"].mean()
    best = int(mean.idxmin())
    assert params == grid[best] and record["best_score"] == pytest.approx(mean.min())
    assert (table["chosen"] == (table["point"] == best)).all() and table["chosen"].sum() == 3
    assert set(table["criterion"]) == {"mae"} and table["score"].dtype == np.float64
    assert list(table.columns) == ["point", "param:gamma", "param:lambda", "resample", "score", "criterion", "chosen"]


def test_a_validation_selection_has_one_resample_and_nothing_to_select_has_no_table(toy):
    train = make_samples(toy.select_segments(["s0", "s1"]), ["y"])
    val = make_samples(toy.select_segments(["s2"]), ["y"])
    method = KRLS(gamma_grid=(-2, 0, 3), lambda_grid=(-3, -1, 2))
    _, record = select(method, train, Selection(kind="validation", criterion="rmae"), np.random.default_rng(0), val)
    table = record["table"].frame()
    assert len(table) == 6 and set(table["resample"]) == {0} and set(table["criterion"]) == {"rmae"}
    one_point = KRLS(gamma_grid=(0, 0, 1), lambda_grid=(-1, -1, 1))
    assert "table" not in select(one_point, train, Selection(), np.random.default_rng(0))[1]
    assert "table" not in select(method, train, Selection(kind="none"), np.random.default_rng(0))[1]


def test_non_numeric_grid_values_are_stored_as_text():
    from enginebench.experiments.selection import SelectionTable

    grid = [{"kind": "rbf", "degree": 1}, {"kind": ("a", 1), "degree": 2}]
    frame = SelectionTable(grid, np.array([[1.0, 2.0], [np.inf, 3.0]]), "mae", 0).frame()
    assert list(frame["param:kind"]) == ["rbf", "rbf", "('a', 1)", "('a', 1)"]
    assert frame["param:degree"].dtype == np.float64 and list(frame["score"]) == [1.0, 2.0, np.inf, 3.0]
    assert list(frame["chosen"]) == [True, True, False, False]


def test_edge_rules_decide_which_grid_edges_are_warned_about():
    from enginebench.experiments.selection import edge_warnings, grid_positions

    space = {"degree": np.array([1, 2, 3]), "alpha": np.array([0.1, 1.0, 10.0])}
    chosen = {"degree": 1, "alpha": 10.0}
    places = grid_positions(space, chosen, {"degree": "high"})
    assert places["degree"] == {"edge": "lower", "value": 1.0, "lower": 1.0, "upper": 3.0, "warn": False}
    assert places["alpha"]["edge"] == "upper" and places["alpha"]["warn"]  # not listed: both edges warned
    assert [w.split(" =")[0] for w in edge_warnings("m", space, chosen, {"degree": "high"})] == ["m: alpha"]
    assert len(edge_warnings("m", space, chosen)) == 2
    assert edge_warnings("m", space, chosen, {"degree": "none", "alpha": "low"}) == []


class UnboundedKRLS(KRLS):
    """KRLS as a plugin without declared bounds: its grids are never extended."""

    def search_bounds(self, data):
        return {}


def test_the_record_names_the_option_that_sets_each_grid(toy):
    train = make_samples(toy.select_segments(["s0", "s1"]), ["y"])
    method = UnboundedKRLS(gamma_grid=(-4, -3, 3), lambda_grid=(-3, -1, 3))
    _, record = select(method, train, Selection(resamples=2), np.random.default_rng(0))
    edges = record["grid_edges"]
    assert edges["gamma"]["option"] == "gamma_grid" and edges["lambda"]["option"] == "lambda_grid"
    assert edges["gamma"]["edge"] == "upper" and edges["gamma"]["upper"] == pytest.approx(1e-3)
    assert any(w.startswith("krls: gamma = 0.001 selected at the upper edge") for w in record["warnings"])


def _noisy_mean_method():
    """A stochastic toy method: the training mean plus a random offset scaled by ``s`` (each fit draws anew)."""
    from enginebench.method import Method

    class Noisy(Method):
        name, family, modes = "noisy", "baseline", frozenset({"static", "window", "simulation"})

        def search_space(self, data):
            return {"s": np.array([0.5, 1.0, 2.0])}

        def fit(self, train, params, rng):
            return float(train.y.mean()) + params["s"] * rng.normal()

        def predict(self, fitted, data):
            return [np.full((len(s.rows), 1), fitted) for s in data.segments]

    return Noisy()


def test_keep_fitted_returns_the_scored_model_of_the_selected_point(toy):
    train = make_samples(toy.select_segments(["s0", "s1"]), ["y"])
    val = make_samples(toy.select_segments(["s2"]), ["y"])
    method = _noisy_mean_method()
    params, record = select(method, train, Selection(kind="validation"), np.random.default_rng(4), val,
                            keep_fitted=True)
    fitted = record["fitted"]
    # the kept model scores the selected point's validation score exactly, and it is the draw of that point
    assert np.abs(val.y - fitted).mean() == record["best_score"]
    rng = np.random.default_rng(4)
    draws = [float(train.y.mean()) + s * rng.normal() for s in (0.5, 1.0, 2.0)]
    assert fitted == draws[[0.5, 1.0, 2.0].index(params["s"])]
    # the same selection without keeping picks the same point and keeps nothing
    again, plain = select(method, train, Selection(kind="validation"), np.random.default_rng(4), val)
    assert again == params and plain["best_score"] == record["best_score"] and "fitted" not in plain


def test_keep_fitted_only_for_a_validation_selection_through_fit_grid(toy):
    train = make_samples(toy.select_segments(["s0", "s1"]), ["y"])
    val = make_samples(toy.select_segments(["s2"]), ["y"])
    _, boot = select(_noisy_mean_method(), train, Selection(resamples=3), np.random.default_rng(0), keep_fitted=True)
    assert "fitted" not in boot  # resampled fits are not fitted on the whole training part
    krls = KRLS(gamma_grid=(-2, 0, 3), lambda_grid=(-3, -1, 3))  # overrides predict_grid: no models to keep
    _, shared = select(krls, train, Selection(kind="validation"), np.random.default_rng(0), val, keep_fitted=True)
    assert "fitted" not in shared


def test_a_hyperparameter_two_options_set_names_both():
    from enginebench.experiments.selection import edge_rules
    from enginebench.methods.narx import NARX

    _, options = edge_rules(NARX())
    assert options["lags"] == "na and nb" and options["na"] == "na" and options["gamma"] == "gamma_grid"
