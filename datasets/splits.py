"""Temporal and group splits: train on the past (or on other groups), test on the rest.

Never a random shuffle across time. Each splitter returns one or more ``Split``s whose
parts are Datasets; ``validation`` is present only where the split defines one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.errors import DataError, SpecError

SPLIT_KINDS = ("published", "holdout", "rolling", "groups")


@dataclass(frozen=True)
class Split:
    """A training part, a test part and optionally a validation part."""

    name: str
    train: Dataset
    test: Dataset
    validation: Dataset | None = None

    def parts(self) -> dict[str, Dataset]:
        out = {"test": self.test}
        if self.validation is not None:
            out["validation"] = self.validation
        return out


def _nonempty(split: Split) -> Split:
    for part, ds in (("train", split.train), *split.parts().items()):
        if len(ds) == 0:
            raise DataError(f"split {split.name!r}: the {part} part is empty; check the split settings")
    return split


def published(ds: Dataset) -> list[Split]:
    """The dataset's own split (meta['published_split']: part -> segment ids)."""
    spec = ds.meta.get("published_split")
    if not spec:
        raise SpecError(f"dataset {ds.name!r} has no published split; use kind = 'holdout', 'rolling' or 'groups'")
    for part in ("train", "test"):
        if part not in spec:
            raise DataError(f"dataset {ds.name!r}: published split lacks the {part!r} part")
    val = spec.get("validation")
    return [_nonempty(Split(
        "published",
        train=ds.select_segments(spec["train"]),
        test=ds.select_segments(spec["test"]),
        validation=ds.select_segments(val) if val else None,
    ))]


def _time_order(ds: Dataset) -> np.ndarray:
    """Row positions ordered by time across segments (segments ordered by their start)."""
    return np.lexsort((np.arange(len(ds)), ds.frame[TIME].to_numpy()))


def holdout(ds: Dataset, test_fraction: float = 0.3, validation_fraction: float = 0.0) -> list[Split]:
    """Block holdout by time: the last ``test_fraction`` of samples (in time) is the test set."""
    if not 0 < test_fraction < 1 or not 0 <= validation_fraction < 1 - test_fraction:
        raise SpecError(
            f"holdout fractions must satisfy 0 < test_fraction < 1 and 0 <= validation_fraction < 1 - test_fraction; "
            f"got test_fraction={test_fraction}, validation_fraction={validation_fraction}"
        )
    order = _time_order(ds)
    n = len(order)
    n_test = int(round(n * test_fraction))
    n_val = int(round(n * validation_fraction))
    label = np.zeros(n, dtype=np.int8)  # 0 train, 1 validation, 2 test
    label[order[n - n_test:]] = 2
    label[order[n - n_test - n_val:n - n_test]] = 1
    return [_nonempty(Split(
        "holdout",
        train=ds.rows(label == 0),
        test=ds.rows(label == 2),
        validation=ds.rows(label == 1) if n_val else None,
    ))]


def rolling(ds: Dataset, folds: int = 3, test_fraction: float = 0.2) -> list[Split]:
    """Rolling origin: fold k trains on everything before origin k and tests on the next block.

    The last ``test_fraction`` of time is cut into ``folds`` equal test blocks; the
    training window expands with each origin.
    """
    if folds < 1 or not 0 < test_fraction < 1:
        raise SpecError(f"rolling split needs folds >= 1 and 0 < test_fraction < 1; got folds={folds}, test_fraction={test_fraction}")
    order = _time_order(ds)
    n = len(order)
    start = n - int(round(n * test_fraction))
    edges = np.linspace(start, n, folds + 1).round().astype(int)
    splits = []
    for k in range(folds):
        train = np.zeros(n, dtype=bool)
        test = np.zeros(n, dtype=bool)
        train[order[: edges[k]]] = True
        test[order[edges[k]: edges[k + 1]]] = True
        splits.append(_nonempty(Split(f"rolling-{k + 1}", train=ds.rows(train), test=ds.rows(test))))
    return splits


def groups(ds: Dataset, column: str, test: list[Any], validation: list[Any] | None = None) -> list[Split]:
    """Leave groups out: every row whose ``column`` value is in ``test`` goes to the test set."""
    if column not in ds.schema or ds.schema[column].role != "group":
        raise SpecError(f"split by groups needs a column with role 'group'; {column!r} is not one (groups: {ds.schema.groups})")
    values = ds.frame[column].astype(str).to_numpy()
    known = set(values)
    for name, wanted in (("test", test), ("validation", validation or [])):
        unknown = {str(v) for v in wanted} - known
        if unknown:
            raise SpecError(f"split by {column!r}: unknown {name} group(s) {', '.join(sorted(unknown))}")
    is_test = np.isin(values, [str(v) for v in test])
    is_val = np.isin(values, [str(v) for v in (validation or [])])
    if np.any(is_test & is_val):
        raise SpecError(f"split by {column!r}: a group is both in test and validation")
    return [_nonempty(Split(
        f"groups:{column}",
        train=ds.rows(~is_test & ~is_val),
        test=ds.rows(is_test),
        validation=ds.rows(is_val) if validation else None,
    ))]


def make_splits(ds: Dataset, kind: str = "published", **options: Any) -> list[Split]:
    """Dispatch on the split kind of an experiment spec."""
    funcs = {"published": published, "holdout": holdout, "rolling": rolling, "groups": groups}
    if kind not in funcs:
        raise SpecError(f"unknown split kind {kind!r}; use one of {', '.join(SPLIT_KINDS)}")
    try:
        return funcs[kind](ds, **options)
    except TypeError as exc:
        raise SpecError(f"split {kind!r}: {exc}") from None


def blocked_folds(n: int, k: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """K contiguous blocks of 0..n-1 (in time order): (train, validation) index pairs."""
    if k < 2 or k > n:
        raise SpecError(f"blocked k-fold needs 2 <= k <= n; got k={k}, n={n}")
    edges = np.linspace(0, n, k + 1).round().astype(int)
    idx = np.arange(n)
    return [(np.r_[idx[: edges[j]], idx[edges[j + 1]:]], idx[edges[j]: edges[j + 1]]) for j in range(k)]
