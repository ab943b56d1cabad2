"""Where in the operating map a model is wrong: its error binned over two inputs (speed x load).

An engine engineer reads a model's error against the operating point, not against time: a
virtual sensor that is good on average may fail at high load, or where the test drove the
engine outside what the training records covered. :func:`operating_map` bins the evaluated
rows over two run-time inputs (even bins over the range both the training and the evaluated
rows span, so extrapolation shows as bins with test rows but no training rows) and gives, per
bin, the RMSE of each method, the rows evaluated and the training rows. Pure numerics: the
report draws it (``reports/interactive_figures.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

BINS = 10
"""Bins per axis by default."""


@dataclass(frozen=True)
class OperatingMap:
    """RMSE per bin of two inputs; ``rmse[m]``, ``rows`` and ``train_rows`` are (bins_y, bins_x) arrays."""

    x_name: str
    y_name: str
    x_edges: np.ndarray
    y_edges: np.ndarray
    rmse: dict[str, np.ndarray]
    """Per method: RMSE of the evaluated rows in each bin (nan where none)."""
    rows: np.ndarray
    train_rows: np.ndarray

    @property
    def extrapolated(self) -> np.ndarray:
        """Bins holding evaluated rows but no training row."""
        return (self.rows > 0) & (self.train_rows == 0)


def _edges(train: np.ndarray, evaluated: np.ndarray, bins: int) -> np.ndarray:
    both = np.concatenate([train[np.isfinite(train)], evaluated[np.isfinite(evaluated)]])
    lo, hi = (float(both.min()), float(both.max())) if both.size else (0.0, 1.0)
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    return np.linspace(lo, hi, bins + 1)


def _index(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin of each value; the top edge belongs to the last bin."""
    return np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 2)


def operating_map(
    x: np.ndarray, y: np.ndarray, truth: np.ndarray, predictions: Mapping[str, np.ndarray],
    train_x: np.ndarray, train_y: np.ndarray, *, names: tuple[str, str] = ("x", "y"), bins: int = BINS,
) -> OperatingMap:
    """Bin the evaluated rows (inputs ``x``, ``y``; measured ``truth``) and each method's predictions."""
    x, y, truth = (np.asarray(a, dtype=float) for a in (x, y, truth))
    train_x, train_y = np.asarray(train_x, dtype=float), np.asarray(train_y, dtype=float)
    xe, ye = _edges(train_x, x, bins), _edges(train_y, y, bins)
    cell = _index(y, ye) * bins + _index(x, xe)
    rows = np.bincount(cell, minlength=bins * bins).reshape(bins, bins)
    tcell = _index(train_y, ye) * bins + _index(train_x, xe)
    train_rows = np.bincount(tcell, minlength=bins * bins).reshape(bins, bins)
    rmse = {}
    for method, pred in predictions.items():
        sq = np.bincount(cell, weights=np.square(np.asarray(pred, dtype=float) - truth), minlength=bins * bins)
        with np.errstate(invalid="ignore", divide="ignore"):
            rmse[method] = np.sqrt(sq.reshape(bins, bins) / rows)
        rmse[method][rows == 0] = np.nan
    return OperatingMap(names[0], names[1], xe, ye, rmse, rows, train_rows)
