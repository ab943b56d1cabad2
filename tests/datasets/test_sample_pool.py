"""The lazy sample pool builds exactly the features of the eager definition, for any rows asked."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.datasets.pools import RawSegments, SamplePool, make_samples
from enginebench.errors import DataError


def reference_window_features(U: np.ndarray, Y: np.ndarray, lags: int) -> np.ndarray:
    """Row t (t >= lags): u_j(t), u_j(t-1), ..., u_j(t-lags) per input, then y(t-1), ..., y(t-lags) per target."""
    rows = []
    for t in range(lags, len(U)):
        row = [U[t - k, j] for j in range(U.shape[1]) for k in range(lags + 1)]
        row += [Y[t - k, j] for j in range(Y.shape[1]) for k in range(1, lags + 1)]
        rows.append(row)
    return np.array(rows)


@pytest.mark.parametrize("lags", [0, 1, 3])
def test_window_features_match_the_definition(toy, lags):
    target = toy.schema.outputs[0]
    samples = make_samples(toy, [target], "window", lags * toy.dt)
    for seg, (sid, part) in zip(samples.segments, toy.segments()):
        U = part[toy.schema.inputs].to_numpy(float)
        Y = part[[target]].to_numpy(float)
        np.testing.assert_array_equal(seg.X, reference_window_features(U, Y, lags))
        np.testing.assert_array_equal(seg.y, Y[lags:])
        assert seg.id == sid


@pytest.mark.parametrize("mode, window", [("static", 0.0), ("window", 2.0), ("simulation", 0.0)])
def test_take_and_batches_equal_the_materialised_samples(toy, mode, window):
    target = toy.schema.outputs[0]
    pool = SamplePool(RawSegments.from_dataset(toy), [target], mode, window)
    full = pool.materialize()
    assert len(pool) == len(full) and list(pool.segment_sizes) == [len(s) for s in full.segments]
    rng = np.random.default_rng(0)
    index = rng.integers(0, len(pool), 57)  # repeats and any order, as a bootstrap draws them
    a, b = pool.take(index), full.take(index)
    assert a.segment_ids() == b.segment_ids()
    np.testing.assert_array_equal(a.X, b.X)
    np.testing.assert_array_equal(a.y, b.y)
    for sa, sb in zip(a.segments, b.segments):
        np.testing.assert_array_equal(sa.rows, sb.rows)
    blocks = list(pool.batches(50))
    assert all(len(blk) <= 50 for blk in blocks)
    np.testing.assert_array_equal(np.concatenate([blk.X for blk in blocks]), full.X)
    np.testing.assert_array_equal(np.concatenate([blk.y for blk in blocks]), full.y)


def test_one_raw_copy_serves_every_target_and_window(toy):
    raw = RawSegments.from_dataset(toy)
    pools = [SamplePool(raw, [t], "window", w) for t in toy.schema.outputs for w in (0.0, 3.0)]
    first = pools[0].take(np.arange(5)).segments[0].U
    assert all(p.take(np.arange(5)).segments[0].U is first for p in pools)


def test_pool_refuses_a_target_that_is_not_an_output(toy):
    raw = RawSegments.from_dataset(toy)
    with pytest.raises(DataError, match=r"column 'nope' is not an 'output' column"):
        SamplePool(raw, ["nope"], "static")


@pytest.mark.parametrize("mode, window", [("static", 0.0), ("window", 2.0)])
def test_batches_without_features_keep_rows_targets_and_inputs(toy, mode, window):
    """features=False (a method with uses_features = False): X has no columns; all else as with features."""
    target = toy.schema.outputs[0]
    pool = SamplePool(RawSegments.from_dataset(toy), [target], mode, window)
    with_x, bare = list(pool.batches(50)), list(pool.batches(50, features=False))
    assert len(with_x) == len(bare)
    for a, b in zip(with_x, bare):
        assert b.X.shape == (len(a), 0)
        np.testing.assert_array_equal(a.y, b.y)
        assert a.segment_ids() == b.segment_ids()
        for sa, sb in zip(a.segments, b.segments):
            np.testing.assert_array_equal(sa.rows, sb.rows)
            assert sa.U is sb.U
