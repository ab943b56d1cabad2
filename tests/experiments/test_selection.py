"""Model selection: resampling units, the validation scheme, and trajectory-preserving subsamples."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.datasets.samples import make_samples
from enginebench.errors import MethodError
from enginebench.experiments.jobs import subsample, subsample_segments
from enginebench.experiments.selection import grid_scores, resample_pairs, select
from enginebench.experiments.spec import Selection
from enginebench.methods.krls import KRLS


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
    from enginebench.methods.base import grid_points

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
