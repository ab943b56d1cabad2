"""Repeated training rows merged into weighted rows (methods/numerics/repeats.py): exact against the full system."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.methods.numerics.kernels import gaussian, sq_distances
from enginebench.methods.numerics.repeats import RowGroups


def test_groups_in_order_of_first_occurrence() -> None:
    a, b, c = [0.0, 1.0], [2.0, -1.0], [0.0, 1.5]
    groups = RowGroups.of(np.array([a, b, a, c, b, a]))
    np.testing.assert_array_equal(groups.first, [0, 1, 3])
    np.testing.assert_array_equal(groups.group, [0, 1, 0, 2, 1, 0])
    np.testing.assert_array_equal(groups.root_counts, np.sqrt([3.0, 2.0, 1.0]))
    np.testing.assert_array_equal(groups.targets(np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])),
                                  np.array([[10.0 / np.sqrt(3)], [7.0 / np.sqrt(2)], [4.0]]))


def test_distinct_rows_need_no_groups() -> None:
    assert RowGroups.of(np.array([[0.0, 1.0], [0.0, 1.0 + 1e-15]])) is None
    assert RowGroups.of(np.zeros((1, 3))) is None
    assert RowGroups.of(np.zeros((0, 3))) is None


@pytest.mark.parametrize("gamma", [0.05, 1.0, 20.0])
def test_weighted_distinct_rows_give_the_full_systems_predictions(gamma: float) -> None:
    """A bootstrap draw (repeats, and targets that differ within a group, as rows with equal features
    but different measurements): K' = D K_u D, t' = S t / sqrt(c), K_eval' = K_eval_u D solved on the
    distinct rows predict what the full n x n ridge system predicts, for every lambda."""
    rng = np.random.default_rng(4)
    base = rng.normal(size=(40, 3))
    X = base[rng.integers(0, 40, 60)]
    T = np.stack([np.sin(X[:, 0]), X[:, 1]], axis=1) + 0.1 * rng.normal(size=(60, 2))
    Xe = rng.normal(size=(15, 3))
    groups = RowGroups.of(X)
    assert groups is not None and len(groups.first) < 60
    K, Ke = gaussian(sq_distances(X), gamma), gaussian(sq_distances(Xe, X), gamma)
    Xu = X[groups.first]
    Ku, Keu = gaussian(sq_distances(Xu), gamma), gaussian(sq_distances(Xe, Xu), gamma)
    groups.weigh(Ku, Keu)
    Tu = groups.targets(T)
    for lam in (1e-4, 1e-2, 1.0):
        full = Ke @ np.linalg.solve(K + lam * np.eye(60), T)
        collapsed = Keu @ np.linalg.solve(Ku + lam * np.eye(len(Xu)), Tu)
        np.testing.assert_allclose(collapsed, full, rtol=0, atol=1e-10 * np.abs(full).max() / lam ** 0.5)
