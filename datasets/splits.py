"""Temporal and group splits: train on the past (or on other groups), test on the rest.

Never a random shuffle across time. Each splitter returns one or more ``Split``s whose
parts are Datasets; ``validation`` is present only where the split defines one.
"""

from __future__ import annotations

import difflib
import fnmatch
import re
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import pandas as pd

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.errors import DataError, SpecError

SPLIT_KINDS = ("published", "holdout", "rolling", "groups", "records")


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


_ENTRY = re.compile(r"^(?P<name>.*?)\[\s*(?P<start>[+-]?\d*)\s*:\s*(?P<stop>[+-]?\d*)\s*\]$")


def parse_record_entry(entry: str) -> tuple[str, int | None, int | None]:
    """``"rec"`` -> (rec, None, None); ``"rec[100:-50]"`` -> (rec, 100, -50): a record name and a Python slice."""
    text = entry.strip()
    m = _ENTRY.match(text)
    if m is None:
        if "[" in text or "]" in text:
            raise SpecError(f"split records: {entry!r} is not a record name or NAME[start:stop] (sample indices, "
                            "Python slice semantics, no step), e.g. \"est[1000:]\"")
        return text, None, None
    to_int = lambda v: int(v) if v not in ("", "+", "-") else None  # noqa: E731
    return m.group("name").strip(), to_int(m.group("start")), to_int(m.group("stop"))


def _is_pattern(entry: str) -> bool:
    return "*" in entry or "?" in entry


def _expand(entries: Sequence[str], known: list[str], named: set[str], part: str) -> list[str]:
    """Entries with glob patterns (``*``, ``?``) replaced by the records they match, in dataset order, leaving
    out the records another entry names explicitly (``train = ["*"]`` with ``test = ["m17"]``: all but m17)."""
    out: list[str] = []
    for entry in entries:
        if not _is_pattern(entry):
            out.append(entry)
            continue
        if "[" in entry or "]" in entry:
            raise SpecError(f"split records: {entry!r} ({part}) mixes a pattern and a slice; a pattern (* ?) names "
                            "whole records")
        found = [r for r in known if fnmatch.fnmatchcase(r, entry.strip()) and r not in named and r not in out]
        if not found:
            raise SpecError(f"split records: pattern {entry!r} ({part}) matches no record that is not named "
                            f"elsewhere; records: {', '.join(known[:12])}{' ...' if len(known) > 12 else ''}")
        out += found
    return out


def records(ds: Dataset, train: Sequence[str], test: Sequence[str], validation: Sequence[str] | None = None
            ) -> list[Split]:
    """Split by records (segments): each part lists record names, index slices of them (``"rec[40650:]"``) or
    glob patterns of names (``"raw_0*"``; the records another entry names explicitly are left out).

    A record is a segment of the dataset (a file, a column set of a wide file, a value of
    its record column). A sliced entry becomes a segment named as written; slices follow
    Python semantics (negative indices count from the end). No two entries may share a
    sample, within a part or across parts.
    """
    bounds = {sid: (a, b) for sid, a, b in ds.segment_bounds()}
    used: dict[str, list[tuple[int, int, str, str]]] = {}
    frames: dict[str, list[pd.DataFrame]] = {}
    named = {parse_record_entry(e)[0] for e in (*train, *(validation or []), *test) if not _is_pattern(e)}
    for part, entries in (("train", train), ("validation", validation or []), ("test", test)):
        if part != "validation" and not entries:
            raise SpecError(f"split records: the {part} list is empty; name at least one record")
        for entry in _expand(entries, list(bounds), named, part):
            name, start, stop = parse_record_entry(entry)
            if name not in bounds:
                known = list(bounds)
                shown = ", ".join(known[:12]) + (f" ... ({len(known)} records)" if len(known) > 12 else "")
                close = difflib.get_close_matches(name, known, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise SpecError(f"split records: unknown record {name!r} in {part}{hint}; records of dataset "
                                f"{ds.name!r}: {shown}")
            a, b = bounds[name]
            lo, hi, _ = slice(start, stop).indices(b - a)
            if hi - lo < 2:
                raise SpecError(f"split records: {entry!r} ({part}) selects {max(hi - lo, 0)} sample(s) of record "
                                f"{name!r} ({b - a} samples); a part needs at least 2")
            for o_lo, o_hi, o_entry, o_part in used.get(name, []):
                if lo < o_hi and o_lo < hi:
                    raise SpecError(
                        f"split records: {entry!r} ({part}) and {o_entry!r} ({o_part}) share samples "
                        f"{max(lo, o_lo)}..{min(hi, o_hi) - 1} of record {name!r}; make the slices disjoint")
            used.setdefault(name, []).append((lo, hi, entry, part))
            label = name if start is None and stop is None else f"{name}[{lo}:{hi}]"
            frames.setdefault(part, []).append(ds.frame.iloc[a + lo:a + hi].assign(**{SEGMENT: label}))
    part_ds = {part: ds.with_frame(pd.concat(fr, ignore_index=True)) for part, fr in frames.items()}
    return [_nonempty(Split("records", train=part_ds["train"], test=part_ds["test"],
                            validation=part_ds.get("validation")))]


def make_splits(ds: Dataset, kind: str = "published", **options: Any) -> list[Split]:
    """Dispatch on the split kind of an experiment spec."""
    funcs = {"published": published, "holdout": holdout, "rolling": rolling, "groups": groups, "records": records}
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
