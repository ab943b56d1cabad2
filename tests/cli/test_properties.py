"""Property-based tests (hypothesis) of the importer, the import-spec parser, splits, windows and metrics.

Each property states what must hold for *every* input the strategy can draw:

* import: an arbitrary small table either imports with every value read back exactly, or
  fails with one EngineBenchError line that names the file; the command line prints that
  same line after ``error:`` and exits with 2, never a traceback;
* spec parser: an arbitrary spec document either loads with its values or fails with one
  SpecError line naming the spec;
* splits: parts are disjoint, cover the rows they claim, and keep the past before the future;
* windows: row t's features are exactly the inputs at t..t-L and the outputs at t-1..t-L,
  and perturbing y(t) changes no feature of row t;
* metrics: every metric equals a straightforward pure-Python formula.

Examples are few (``max_examples`` 25-60) and ``deadline=None``: the file runs in seconds.
"""

from __future__ import annotations

import csv
import io
import math
import statistics
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomli_w
from click.testing import CliRunner
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st

from enginebench.cli.main import cli
from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.import_spec import ALLOWED_KEYS, ImportSpec, load_spec
from enginebench.datasets.importer import import_table
from enginebench.datasets.pools import RawSegments, SamplePool, make_samples
from enginebench.datasets.schema import Column, Schema
from enginebench.datasets.splits import groups, holdout, rolling
from enginebench.errors import DataError, EngineBenchError, SpecError
from enginebench.results import metrics as M

FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# =========================================================================== the importer
GOOD_CELL = st.one_of(
    st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False).map(repr),
    st.integers(-10**6, 10**6).map(str),
)
BAD_CELL = st.sampled_from(
    ["", "abc", "1e309", "-1e400", "nan", "NaN", "inf", "-inf", "1,5", "NA", "--1", "1e", " ", "0x1F", "1.2.3",
     '"7"', "#", "n/a", "1 2", "TRUE", "\u00b05", "1e-400"]
)
HEADERS = {
    "ok": ["t", "speed", "T_exh"],
    "units": ["t", "speed [rpm]", "T_exh (degC)"],
    "case": ["t", "Speed", "T_exh"],
    "missing": ["t", "speed"],
    "duplicate": ["t", "speed", "T_exh", "speed"],
    "extra": ["t", "speed", "T_exh", "note"],
}
SPEC_TEMPLATE = """name = "prop"
files = ["data.csv"]
time = "t"
dt = 1.0
gap_tolerance = 3.0
{delimiter}
[columns]
speed = {{ role = "input", unit = "rpm" }}
T_exh = {{ role = "output", unit = "degC" }}
"""


@st.composite
def csv_tables(draw: st.DrawFn, valid: bool = False) -> dict:
    """A small CSV table: time steps, cells (mostly numbers, some garbage), header and delimiters.

    ``valid`` draws only tables that are valid by construction (see ``must_import``).
    """
    n = draw(st.integers(2, 7) if valid else st.one_of(st.integers(0, 1), st.integers(2, 7), st.integers(2, 7)))
    step = st.sampled_from([1, 2]) if valid else st.sampled_from([1] * 12 + [2, 2, 5, 0, -1])
    steps = draw(st.lists(step, min_size=max(n - 1, 0), max_size=max(n - 1, 0)))
    t0 = draw(st.integers(-5, 100))
    times = [str(t0 + s) for s in np.r_[0, np.cumsum(steps)].astype(int)][:n]
    garbage = not valid and draw(st.integers(0, 2)) == 0
    cell = st.one_of(GOOD_CELL, GOOD_CELL, GOOD_CELL, BAD_CELL) if garbage else GOOD_CELL
    header_kind = draw(st.sampled_from(["ok", "extra"] if valid else ["ok"] * 12 + list(HEADERS)))
    header = HEADERS[header_kind]
    rows = []
    for i in range(n):
        t = draw(st.one_of(st.just(times[i]), BAD_CELL)) if garbage and draw(st.integers(0, 9)) == 0 else times[i]
        rows.append([t] + [draw(cell) for _ in header[1:]])
    file_delim = draw(st.sampled_from([",", ",", ";", "\t"]))
    spec_delim = file_delim if valid or draw(st.integers(0, 4)) else draw(st.sampled_from([",", ";", "\t"]))
    return {"header": header, "header_kind": header_kind, "rows": rows, "file_delim": file_delim,
            "spec_delim": spec_delim, "steps": steps}


def write_table(folder: Path, table: dict) -> Path:
    """Write the table's data.csv and spec.toml into ``folder``; return the spec path."""
    buf = io.StringIO()
    writer = csv.writer(buf, delimiter=table["file_delim"], lineterminator="\n")
    writer.writerow(table["header"])
    writer.writerows(table["rows"])
    (folder / "data.csv").write_text(buf.getvalue(), encoding="utf-8")
    delim = tomli_w.dumps({"delimiter": table["spec_delim"]}).strip()
    (folder / "spec.toml").write_text(SPEC_TEMPLATE.format(delimiter=delim), encoding="utf-8")
    return folder / "spec.toml"


def read_back(folder: Path, delim: str) -> list[list[str]]:
    """The data rows as the csv module reads them (the unquoted cells)."""
    with open(folder / "data.csv", newline="", encoding="utf-8") as fh:
        return list(csv.reader(fh, delimiter=delim))[1:]


def must_import(table: dict) -> bool:
    """True for tables that are valid by construction: clean numbers, right header, steps of 1-2 dt."""
    rows = table["rows"]
    if table["header_kind"] not in ("ok", "extra") or table["file_delim"] != table["spec_delim"] or len(rows) < 2:
        return False
    if any(s not in (1, 2) for s in table["steps"][: len(rows) - 1]):
        return False
    try:
        values = np.array([[float(c) for c in r] for r in rows])
    except ValueError:
        return False
    if not np.isfinite(values).all() or [r[0] for r in rows] != [str(int(float(r[0]))) for r in rows]:
        return False
    return all(np.ptp(values[:, j]) > 0 for j in (1, 2))


def assert_one_line_error(exc: BaseException, folder: Path) -> None:
    msg = str(exc)
    assert isinstance(exc, EngineBenchError), f"{type(exc).__name__}: {msg}"
    assert msg and "\n" not in msg and "\r" not in msg
    assert msg.startswith(str(folder)), msg  # names the spec or the data file
    assert "Traceback" not in msg


@settings(max_examples=60, deadline=None)
@given(table=csv_tables())
def test_arbitrary_tables_import_exactly_or_fail_with_one_line(table):
    """import_table and `enginebench datasets show` agree: exact values, or one `error:` line and exit 2."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        spec = write_table(folder, table)
        try:
            ds = import_table(spec)
        except Exception as exc:  # noqa: BLE001 - the property: only EngineBenchError, one line
            assert_one_line_error(exc, folder)
            assert not must_import(table), f"a valid table was refused: {exc}"
            error = str(exc)
            event(f"refused: {error.split(': ', 1)[1][:40]}")
        else:
            error = None
            event("imported")
            cells = read_back(folder, table["spec_delim"])
            ref = np.array([[float(c) for c in row[:3]] for row in cells])
            assert len(ds) == len(cells)
            np.testing.assert_array_equal(ds.frame[TIME].to_numpy(), ref[:, 0])
            np.testing.assert_array_equal(ds.frame["speed"].to_numpy(), ref[:, 1])
            np.testing.assert_array_equal(ds.frame["T_exh"].to_numpy(), ref[:, 2])
            gaps = int(np.sum(np.diff(ref[:, 0]) > 3.0))
            assert ds.segment_ids == ["data"] + [f"data#{k}" for k in range(1, gaps + 1)]
        result = CliRunner().invoke(cli, ["datasets", "show", str(spec)], env={"ENGINEBENCH_DATA": tmp})
        if error is None:
            assert result.exit_code == 0, result.output
            assert result.output.startswith(f"prop: {len(ds)} rows")
        else:
            assert result.exit_code == 2 and isinstance(result.exception, SystemExit)
            assert result.output == f"error: {error}\n"


@FAST
@given(table=csv_tables(valid=True).filter(must_import))
def test_valid_tables_always_import(table):
    """The valid-by-construction subset is never refused (the property above could pass vacuously)."""
    with tempfile.TemporaryDirectory() as tmp:
        ds = import_table(write_table(Path(tmp), table))
        assert len(ds) == len(table["rows"])


@settings(max_examples=60, deadline=None)
@given(data=st.one_of(st.binary(max_size=120),
                      st.text(alphabet="0123456789t,;.-+eE \n\r\t\"'abcnNaINF#", max_size=120)))
def test_arbitrary_bytes_never_give_a_traceback(data):
    """Whatever the data file holds, the import ends in a Dataset or one EngineBenchError line."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        raw = data if isinstance(data, bytes) else data.encode("utf-8")
        (folder / "data.csv").write_bytes(raw)
        (folder / "spec.toml").write_text(SPEC_TEMPLATE.format(delimiter=""), encoding="utf-8")
        try:
            ds = import_table(folder / "spec.toml")
        except Exception as exc:  # noqa: BLE001
            assert_one_line_error(exc, folder)
        else:
            assert len(ds) >= 2 and np.isfinite(ds.frame[["speed", "T_exh", TIME]].to_numpy()).all()


# =========================================================================== the spec parser
ANY_VALUE = st.one_of(
    st.booleans(),
    st.integers(-3, 5),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=6),
    st.lists(st.one_of(st.text(max_size=6), st.integers(0, 3)), max_size=3),
    st.dictionaries(st.text(max_size=5), st.one_of(st.text(max_size=5), st.integers(0, 2)), max_size=2),
)
COLUMN_ENTRY = st.one_of(
    st.fixed_dictionaries({"role": st.sampled_from(["input", "output", "internal", "group"])},
                          optional={"unit": st.sampled_from(["rpm", "degC", ""])}),
    st.sampled_from(["input", "output", "inptu"]),
    st.dictionaries(st.sampled_from(["role", "unit", "scale"]), ANY_VALUE, max_size=3),
    ANY_VALUE,
)
VALID_SPEC = {
    "name": "s", "files": ["a.csv"], "time": "t", "dt": 1.0,
    "columns": {"speed": {"role": "input", "unit": "rpm"}, "T_exh": {"role": "output"}},
}


PLAUSIBLE = {
    "name": st.text(min_size=1, max_size=6), "time": st.sampled_from(["t", "time", "speed"]),
    "dt": st.floats(1e-3, 1e3), "gap_tolerance": st.floats(1e-3, 1e4), "time_unit": st.sampled_from(["s", "ms", "h"]),
    "segment": st.sampled_from(["voyage", "t", "speed"]), "delimiter": st.sampled_from([",", ";", "\t", "ab"]),
    "provenance": st.text(max_size=6), "licence": st.text(max_size=6), "min_segment_rows": st.integers(0, 5),
    "drop_short_segments": st.booleans(), "dt_tolerance": st.floats(0, 0.6),
    "files": st.lists(st.sampled_from(["a.csv", "b.parquet", "a.csv"]), max_size=2),
}


@st.composite
def spec_documents(draw: st.DrawFn) -> dict:
    """A valid spec with some keys replaced by plausible or arbitrary values, dropped, or added."""
    doc = {k: (dict(v) if isinstance(v, dict) else v) for k, v in VALID_SPEC.items()}
    for _ in range(draw(st.integers(0, 3))):
        key = draw(st.sampled_from([*ALLOWED_KEYS, "license", "colour"]))
        doc[key] = draw(PLAUSIBLE[key] if key in PLAUSIBLE and draw(st.booleans()) else ANY_VALUE)
    if draw(st.integers(0, 5)) == 0:
        doc.pop(draw(st.sampled_from(list(VALID_SPEC))))
    if isinstance(doc.get("columns"), dict) and draw(st.booleans()):
        name = draw(st.sampled_from(["speed", "T_exh", "t", "segment", "time", "extra", ""]))
        doc["columns"][name] = draw(COLUMN_ENTRY)
    return doc


@settings(max_examples=60, deadline=None)
@given(doc=spec_documents())
def test_arbitrary_spec_documents_load_or_fail_with_one_line(doc):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "spec.toml"
        path.write_text(tomli_w.dumps(doc), encoding="utf-8")
        try:
            spec = load_spec(path)
        except Exception as exc:  # noqa: BLE001
            assert isinstance(exc, SpecError), f"{type(exc).__name__}: {exc}"
            assert "\n" not in str(exc) and str(exc).startswith(f"{path}: ")
            event("refused")
        else:
            event("loaded")
            assert isinstance(spec, ImportSpec)
            assert spec.name == doc["name"] and spec.time == doc.get("time") and spec.dt == float(doc["dt"])
            assert spec.files == tuple(path.parent / f for f in doc["files"])
            assert spec.gap_tolerance == float(doc.get("gap_tolerance", 1.5 * spec.dt)) >= spec.dt
            roles = {k: (v if isinstance(v, str) else v["role"]) for k, v in doc["columns"].items()}
            assert {c.name: c.role for c in spec.schema.columns} == roles
            assert spec.schema.outputs and spec.time not in spec.schema


@settings(max_examples=40, deadline=None)
@given(text=st.text(alphabet='abcdefnmtu_ =[]{}"\',.0123456789\n#', max_size=80))
def test_arbitrary_spec_text_never_gives_a_traceback(text):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "spec.toml"
        path.write_text(text, encoding="utf-8")
        try:
            load_spec(path)
        except SpecError as exc:
            assert "\n" not in str(exc) and str(exc).startswith(f"{path}: ")


# =========================================================================== splits
@st.composite
def datasets(draw: st.DrawFn) -> Dataset:
    """1-5 segments of 1-15 rows at dt = 1 whose times may overlap (several engines at once)."""
    k = draw(st.integers(1, 5))
    parts = []
    rid = 0
    for s in range(k):
        n = draw(st.integers(1, 15))
        start = draw(st.integers(0, 40))
        parts.append(pd.DataFrame({
            SEGMENT: f"s{s}", TIME: start + np.arange(n, dtype=float),
            "x": np.arange(n, dtype=float) * (s + 1), "y": np.sin(np.arange(n) + s),
            "rid": np.arange(rid, rid + n, dtype=float), "g": f"g{draw(st.integers(0, 3))}",
        }))
        rid += n
    schema = Schema((Column("x", "input"), Column("y", "output"), Column("rid", "internal"), Column("g", "group")))
    return Dataset("prop", pd.concat(parts, ignore_index=True), schema, 1.0)


def _rids(ds: Dataset | None) -> np.ndarray:
    return np.empty(0) if ds is None else ds.frame["rid"].to_numpy()


def _time_rank(ds: Dataset) -> dict[float, int]:
    """Each row's position in time order (ties broken by row order), keyed by row id."""
    order = np.lexsort((ds.frame["rid"].to_numpy(), ds.frame[TIME].to_numpy()))
    return {float(ds.frame["rid"].iloc[i]): pos for pos, i in enumerate(order)}


def _is_subsequence(part: Dataset, ds: Dataset) -> bool:
    """The part keeps the dataset's row order and each row's values and segment."""
    merged = part.frame.merge(ds.frame, on="rid", suffixes=("", "_orig"))
    same = all((merged[c] == merged[f"{c}_orig"]).all() for c in (SEGMENT, TIME, "x", "y", "g"))
    return same and len(merged) == len(part) and bool(np.all(np.diff(_rids(part)) > 0))


@FAST
@given(ds=datasets(), test_fraction=st.floats(0.05, 0.9), validation_fraction=st.floats(0.0, 0.9))
def test_holdout_parts_are_disjoint_time_ordered_and_cover_all(ds, test_fraction, validation_fraction):
    assume(validation_fraction < 1 - test_fraction)
    n = len(ds)
    n_test, n_val = round(n * test_fraction), round(n * validation_fraction)
    try:
        (split,) = holdout(ds, test_fraction=test_fraction, validation_fraction=validation_fraction)
    except DataError as exc:
        assert n_test == 0 or n - n_test - n_val <= 0, exc  # only an empty part is refused
        return
    train, val, test = _rids(split.train), _rids(split.validation), _rids(split.test)
    assert len(test) == n_test and len(val) == n_val
    assert sorted(np.r_[train, val, test]) == sorted(_rids(ds))  # disjoint and covering
    rank = _time_rank(ds)
    blocks = [[rank[r] for r in part] for part in (train, val, test) if len(part)]
    for before, after in zip(blocks, blocks[1:]):
        assert max(before) < min(after)  # the past strictly before the future
    for part in (split.train, split.test, *([split.validation] if split.validation is not None else [])):
        assert _is_subsequence(part, ds)


@FAST
@given(ds=datasets(), folds=st.integers(1, 4), test_fraction=st.floats(0.05, 0.9))
def test_rolling_folds_expand_and_test_the_next_block(ds, folds, test_fraction):
    try:
        splits = rolling(ds, folds=folds, test_fraction=test_fraction)
    except DataError:
        n = len(ds)
        edges = np.linspace(n - round(n * test_fraction), n, folds + 1).round().astype(int)
        assert edges[0] == 0 or np.any(np.diff(edges) == 0)  # only an empty part is refused
        return
    rank = _time_rank(ds)
    tested: list[float] = []
    for k, split in enumerate(splits):
        train, test = _rids(split.train), _rids(split.test)
        assert not set(train) & set(test)
        assert max(rank[r] for r in train) < min(rank[r] for r in test)
        assert max(rank[r] for r in train) + 1 == min(rank[r] for r in test)  # the very next block
        if k:
            assert set(train) == set(_rids(splits[k - 1].train)) | set(_rids(splits[k - 1].test))
        assert not set(tested) & set(test)
        tested += list(test)
    n = len(ds)
    assert sorted(rank[r] for r in tested) == list(range(n - round(n * test_fraction), n))


@FAST
@given(ds=datasets(), data=st.data())
def test_group_split_keeps_each_group_on_one_side(ds, data):
    values = sorted(set(ds.frame["g"]))
    test = data.draw(st.lists(st.sampled_from(values), min_size=1, unique=True))
    rest = [v for v in values if v not in test]
    val = data.draw(st.lists(st.sampled_from(rest), unique=True)) if rest else []
    try:
        (split,) = groups(ds, "g", test, val or None)
    except DataError:
        assert not rest or set(rest) == set(val)  # the training part would be empty
        return
    parts = {"train": split.train, "test": split.test, **({"validation": split.validation} if val else {})}
    seen = {name: set(p.frame["g"]) for name, p in parts.items()}
    assert seen["test"] == set(test) and seen.get("validation", set()) == set(val)
    assert seen["train"] == set(values) - set(test) - set(val)
    assert sorted(np.concatenate([_rids(p) for p in parts.values()])) == sorted(_rids(ds))


# =========================================================================== windows
@st.composite
def window_cases(draw: st.DrawFn) -> tuple[Dataset, int]:
    """Segments of arbitrary length, 1-2 inputs, 1-2 outputs, and a number of lags 0-4."""
    lags = draw(st.integers(0, 4))
    lengths = draw(st.lists(st.integers(1, 12), min_size=1, max_size=3))
    n_in = draw(st.integers(1, 2))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    parts = []
    for s, n in enumerate(lengths):
        cols = {f"u{j}": rng.normal(size=n) for j in range(n_in)}
        parts.append(pd.DataFrame({SEGMENT: f"s{s}", TIME: 100.0 * s + np.arange(n), **cols,
                                   "y": rng.normal(size=n), "z": rng.normal(size=n)}))
    schema = Schema((*(Column(f"u{j}", "input") for j in range(n_in)), Column("y", "output"), Column("z", "output")))
    return Dataset("win", pd.concat(parts, ignore_index=True), schema, 1.0), lags


def _reference_row(seg: pd.DataFrame, inputs: list[str], targets: list[str], t: int, lags: int) -> np.ndarray:
    """Inputs at t, t-1, ..., t-L (per input), then outputs at t-1, ..., t-L (per target)."""
    feats = [seg[c].iloc[t - k] for c in inputs for k in range(lags + 1)]
    feats += [seg[c].iloc[t - k] for c in targets for k in range(1, lags + 1)]
    return np.array(feats, dtype=float)


@FAST
@given(case=window_cases(), data=st.data())
def test_window_features_are_the_past_and_never_y_at_t(case, data):
    ds, lags = case
    targets = data.draw(st.sampled_from([["y"], ["y", "z"]]))
    inputs = list(ds.schema.inputs)
    if min(b - a for _, a, b in ds.segment_bounds()) <= lags:
        with pytest.raises(DataError, match="shorter than the window"):
            make_samples(ds, targets, "window", float(lags))
        return
    samples = make_samples(ds, targets, "window", float(lags))
    for (sid, part), seg in zip(ds.segments(), samples.segments):
        assert seg.id == sid and list(seg.rows) == list(range(lags, len(part)))
        for i, t in enumerate(seg.rows):
            np.testing.assert_array_equal(seg.X[i], _reference_row(part, inputs, targets, int(t), lags))
            np.testing.assert_array_equal(seg.y[i], part[targets].iloc[int(t)].to_numpy())
    # perturb y(t) at one raw position: row t's features are unchanged, rows t+1..t+L see it
    k = data.draw(st.integers(0, len(samples.segments) - 1))
    sid, a, b = ds.segment_bounds()[k]
    r = data.draw(st.integers(0, b - a - 1))
    frame = ds.frame.copy()
    frame.loc[a + r, targets[0]] += 1e6
    poked = make_samples(ds.with_frame(frame), targets, "window", float(lags))
    before, after = samples.segments[k], poked.segments[k]
    for i, t in enumerate(before.rows):
        changed = not np.array_equal(before.X[i], after.X[i])
        assert changed == (t - lags <= r < t), (t, r, lags)
    # building features on demand for a random subset gives the same rows
    idx = np.array(data.draw(st.lists(st.integers(0, len(samples) - 1), min_size=1, max_size=6)))
    pool = SamplePool(RawSegments.from_dataset(ds, outputs=targets), targets, "window", float(lags))
    sub = pool.take(idx)
    order = np.argsort(np.searchsorted(np.cumsum(samples.segment_sizes), idx, side="right"), kind="stable")
    np.testing.assert_array_equal(sub.X, samples.X[idx[order]])
    np.testing.assert_array_equal(sub.y, samples.y[idx[order]])


# =========================================================================== metrics
FINITE = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)


@st.composite
def segment_pairs(draw: st.DrawFn) -> tuple[list[list[float]], list[list[float]]]:
    lengths = draw(st.lists(st.integers(1, 12), min_size=1, max_size=4))
    truth = [draw(st.lists(FINITE, min_size=n, max_size=n)) for n in lengths]
    if draw(st.booleans()):  # predictions near the truth, as a fitted model gives
        pred = [[v + draw(st.floats(-5, 5)) for v in seg] for seg in truth]
    else:
        pred = [draw(st.lists(FINITE, min_size=n, max_size=n)) for n in lengths]
    return truth, pred


def _close(a: float, b: float, scale: float = 1.0) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9 * max(1.0, scale))


def _pearson(t: list[float], p: list[float]) -> float:
    """Pearson's r by its definition, on each series divided by its largest magnitude first (r is
    scale-free), so that tiny spreads do not underflow when squared."""
    t = [a / max(map(abs, t)) for a in t]
    p = [b / max(map(abs, p)) for b in p]
    n = len(t)
    mt, mp = math.fsum(t) / n, math.fsum(p) / n
    sxy = math.fsum((a - mt) * (b - mp) for a, b in zip(t, p))
    sxx = math.fsum((a - mt) ** 2 for a in t)
    syy = math.fsum((b - mp) ** 2 for b in p)
    return sxy / math.sqrt(sxx * syy)


@settings(max_examples=60, deadline=None)
@given(pair=segment_pairs())
def test_every_metric_matches_its_reference_formula(pair):
    truth, pred = pair
    t = [v for seg in truth for v in seg]
    p = [v for seg in pred for v in seg]
    n = len(t)
    err = [b - a for a, b in zip(t, p)]
    scale = max(map(abs, t + p))
    ref_mae = math.fsum(abs(e) for e in err) / n
    ref_rmse = math.sqrt(math.fsum(e * e for e in err) / n)
    assert _close(M.mae(t, p), ref_mae, scale)
    assert _close(M.rmse(t, p), ref_rmse, scale)
    mean_t = math.fsum(t) / n
    ss_tot = math.fsum((a - mean_t) ** 2 for a in t)
    if len(set(t)) == 1:
        with pytest.raises(DataError, match="R\\^2 is undefined: target constant"):
            M.r2(t, p)
    elif ss_tot > 1e-6 * scale**2:
        ref_r2 = 1 - math.fsum(e * e for e in err) / ss_tot
        assert math.isclose(M.r2(t, p), ref_r2, rel_tol=1e-7, abs_tol=1e-7)
    r = M.ppmcc(t, p)
    if len(set(t)) == 1 or len(set(p)) == 1:
        assert math.isnan(r)
    elif statistics.pstdev(t) > 1e-6 * scale and statistics.pstdev(p) > 1e-6 * scale:
        assert math.isclose(r, _pearson(t, p), rel_tol=1e-7, abs_tol=1e-7) and -1 <= r <= 1
    absolute = [abs(a) for a in t]
    floor = 1e-3 * math.fsum(absolute) / n
    if all(a >= floor and a > 1e-8 * max(absolute) for a in absolute):
        ref_mape = 100 * math.fsum(abs(e) / abs(a) for e, a in zip(err, t)) / n
        assert math.isclose(M.mape(t, p), ref_mape, rel_tol=1e-9)
    else:
        with pytest.raises(DataError, match=r"^MAPE is undefined: \d+ target values? (is|are) within "):
            M.mape(t, p)
    # RMAE: each segment's MAE, averaged over segments, over the training scale, in %
    train_scale = 1.0 + math.fsum(absolute) / n
    seg_mae = [math.fsum(abs(b - a) for a, b in zip(ts, ps)) / len(ts) for ts, ps in zip(truth, pred)]
    seg_rmae = [m / train_scale * 100 for m in seg_mae]
    got = M.segment_rmae(truth, pred, train_scale)
    assert len(got) == len(truth) and all(_close(g, e, max(seg_rmae)) for g, e in zip(got, seg_rmae))
    assert _close(M.rmae(truth, pred, train_scale), math.fsum(seg_rmae) / len(seg_rmae), max(seg_rmae))
    summary = M.segment_summary(seg_rmae)
    assert _close(summary["median"], statistics.median(seg_rmae), max(seg_rmae))
    if len(seg_rmae) > 1:
        assert math.isclose(summary["sd"], statistics.stdev(seg_rmae), rel_tol=1e-7, abs_tol=1e-9 * max(seg_rmae))
        q = statistics.quantiles(seg_rmae, n=4, method="inclusive")
        assert _close(summary["iqr"], q[2] - q[0], max(seg_rmae))
    else:
        assert math.isnan(summary["sd"]) and summary["iqr"] == 0
    # compute_metrics reports the same numbers (undefined ones as nan with a note)
    values, notes = M.compute_metrics(truth, pred, train_scale)
    assert _close(values["mae"], ref_mae, scale) and _close(values["rmse"], ref_rmse, scale)
    assert values["n"] == n and values["n_segments"] == len(truth)
    assert _close(values["rmae"], summary["mean"], max(seg_rmae))
    for key in ("r2", "ppmcc", "mape"):
        assert math.isnan(values[key]) == (key in notes)


@settings(max_examples=60, deadline=None)
@given(method=st.floats(0, 1e6), baseline=st.floats(1e-6, 1e6))
def test_skill_is_one_minus_the_error_ratio(method, baseline):
    assert _close(M.skill(method, baseline), 1 - method / baseline, method / baseline)
    assert (M.skill(method, baseline) > 0) == (method < baseline)
