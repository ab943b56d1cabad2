"""Splits keep time order and groups apart; windows never offer y(t) to a model."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.datasets.pools import make_samples
from enginebench.datasets.splits import blocked_folds, groups, holdout, make_splits, published, rolling
from enginebench.errors import DataError, SpecError
from enginebench.methods.krls import KRLS
from enginebench.methods.naive import NaiveLast


def test_published_split_uses_segment_ids(toy):
    (split,) = published(toy)
    assert split.train.segment_ids == ["s0", "s1", "s2"]
    assert split.test.segment_ids == ["s3"]
    assert split.validation is None


def test_holdout_is_the_last_block_in_time(toy):
    (split,) = holdout(toy, test_fraction=0.25, validation_fraction=0.25)
    t_train, t_val, t_test = (p.frame["time"].to_numpy() for p in (split.train, split.validation, split.test))
    assert len(t_train) + len(t_val) + len(t_test) == len(toy)
    assert t_train.max() < t_val.min() and t_val.max() < t_test.min()
    assert len(t_test) == round(0.25 * len(toy))


def test_rolling_origin_expands_training_and_never_looks_ahead(toy):
    splits = rolling(toy, folds=3, test_fraction=0.3)
    sizes = [len(s.train) for s in splits]
    assert sizes == sorted(sizes) and len(set(sizes)) == 3
    for s in splits:
        assert s.train.frame["time"].max() < s.test.frame["time"].min()


def test_leave_groups_out_keeps_groups_on_one_side(toy):
    (split,) = groups(toy, "unit", test=["g1"])
    assert set(split.train.frame["unit"]) == {"g0"}
    assert set(split.test.frame["unit"]) == {"g1"}


def test_split_errors_are_precise(toy):
    with pytest.raises(SpecError, match=r"unknown split kind 'random'; use one of published, holdout, rolling, groups, records"):
        make_splits(toy, kind="random")
    with pytest.raises(SpecError, match=r"split by 'unit': unknown test group\(s\) g7"):
        groups(toy, "unit", test=["g7"])
    with pytest.raises(SpecError, match="'u1' is not one"):
        groups(toy, "u1", test=["x"])


def test_blocked_folds_are_contiguous_and_cover_everything():
    folds = blocked_folds(10, 3)
    assert [list(v) for _, v in folds] == [[0, 1, 2], [3, 4, 5, 6], [7, 8, 9]]
    for fit, val in folds:
        assert sorted(np.r_[fit, val]) == list(range(10))


def test_window_features_hold_past_outputs_only(toy):
    s = make_samples(toy, ["y"], "window", 3.0)
    seg = s.segments[0]
    raw = toy.frame[toy.frame["segment"] == "s0"]
    y, u1 = raw["y"].to_numpy(), raw["u1"].to_numpy()
    row = 10  # evaluated time index t = rows[row]
    t = seg.rows[row]
    names = list(s.feature_names)
    assert names[:4] == ["u1[t]", "u1[t-1]", "u1[t-2]", "u1[t-3]"]
    assert [n for n in names if n.startswith("y")] == ["y[t-1]", "y[t-2]", "y[t-3]"]
    assert seg.X[row, names.index("u1[t-2]")] == u1[t - 2]
    assert seg.X[row, names.index("y[t-1]")] == y[t - 1]
    assert seg.X[row, names.index("y[t-3]")] == y[t - 3]
    assert seg.y[row, 0] == y[t]
    assert seg.rows[0] == 3  # the first 3 rows have incomplete windows


@pytest.mark.parametrize("method", [KRLS(gamma_grid=(-1, -1, 1), lambda_grid=(-2, -2, 1)), NaiveLast()])
def test_a_model_cannot_see_y_at_t(toy, method):
    """Changing y(t) changes no feature of row t and no prediction at t."""
    train = make_samples(toy.select_segments(["s0", "s1"]), ["y"], "window", 2.0)
    rng = np.random.default_rng(0)
    params = {"gamma": 0.1, "lambda": 0.01} if method.name == "krls" else {}
    fitted = method.fit(train, params, rng)
    test_ds = toy.select_segments(["s3"])
    base = make_samples(test_ds, ["y"], "window", 2.0)
    t_star = 40
    frame = test_ds.frame.copy()
    frame.loc[frame.index[t_star], "y"] += 1e6  # a wild change to y(t*)
    poked = make_samples(test_ds.with_frame(frame), ["y"], "window", 2.0)
    row = int(np.flatnonzero(base.segments[0].rows == t_star)[0])
    assert np.array_equal(base.segments[0].X[row], poked.segments[0].X[row])
    p_base = method.predict(fitted, base.without_targets())[0]
    p_poked = method.predict(fitted, poked.without_targets())[0]
    assert p_base[row] == pytest.approx(p_poked[row], rel=0, abs=0)
    assert not np.allclose(p_base[row + 1], p_poked[row + 1])  # y(t*) is a feature of t*+1: it does matter there


def test_prediction_view_carries_no_targets(toy):
    s = make_samples(toy, ["y"], "static").without_targets()
    assert all(seg.y is None for seg in s.segments)
    with pytest.raises(DataError, match="carry no targets"):
        s.y


def test_window_errors(toy):
    with pytest.raises(DataError, match=r"segment 's0': 120 rows, shorter than the window of 201 samples"):
        make_samples(toy, ["y"], "window", 200.0)
    with pytest.raises(DataError, match="window 1.5 s is not a multiple of the sample period 1.0 s"):
        make_samples(toy, ["y"], "window", 1.5)
    with pytest.raises(DataError, match="column 'u1' has role 'input'; only 'output' columns can be targets"):
        make_samples(toy, ["u1"], "static")
    with pytest.raises(DataError, match="needs mode 'window'"):
        make_samples(toy, ["y"], "static", 2.0)


def test_take_groups_rows_by_segment(toy):
    s = make_samples(toy, ["y"], "static")
    sizes = [len(seg) for seg in s.segments]
    idx = np.array([sizes[0] + 5, 3, 3, sizes[0] + 1])
    sub = s.take(idx)
    assert [len(seg) for seg in sub.segments] == [2, 2]
    assert np.array_equal(sub.segments[0].rows, [3, 3])
    assert np.array_equal(sub.segments[1].rows, [5, 1])
    assert np.array_equal(sub.y[:, 0], s.y[np.sort(idx, kind="stable")[[0, 1]].tolist() + [sizes[0] + 5, sizes[0] + 1], 0])
