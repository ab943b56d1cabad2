"""User-data import: the malformed corpus with exact messages, the good example, spec and time handling."""

from __future__ import annotations

import dataclasses
import json
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.import_spec import ImportSpec, load_spec
from enginebench.datasets.importer import import_table
from enginebench.datasets.io import read_dataset, write_dataset
from enginebench.datasets.schema import Schema
from enginebench.datasets.validate import validate_frame
from enginebench.errors import DataError, EngineBenchError, SpecError

DATA = Path(__file__).resolve().parents[1] / "data"
MALFORMED = DATA / "malformed"
GOOD = DATA / "good"

ALLOWED = (
    "name, dt, columns, files, header, names, records, time, time_unit, gap_tolerance, segment, record, rate_column, "
    "period_column, delimiter, decimal, sheet, encoding, skip_lines, units_row, provenance, licence, min_segment_rows, drop_short_segments, dt_tolerance, physical_model"
)
CASES: dict[str, tuple[type[EngineBenchError], str]] = {
    "wrong_delimiter": (
        DataError,
        "{dir}/data.csv: time column 't' is not in the header read with delimiter ',' (nor 'speed', 'T_exh'); "
        'the header contains \';\': set delimiter = ";" in the spec',
    ),
    "units_in_header": (
        DataError,
        "{dir}/data.csv: declared column 'speed' is not in the file (nor 'T_exh'); the header has 'speed [rpm]': "
        "units belong in [columns] of the spec, not in the header; rename that header to 'speed'",
    ),
    "mixed_time_zones": (
        DataError,
        "{dir}/data.csv, column 't': mixed time zones: line 2 has offset +01:00, line 5 has offset +02:00; "
        "write every stamp with one UTC offset (e.g. all in UTC)",
    ),
    "duplicate_stamps": (
        DataError,
        "{dir}/data.csv, column 't', lines 5 and 6: duplicate time stamp 3 in segment 'data'; remove the repeated row",
    ),
    "non_monotonic": (
        DataError,
        "{dir}/data.csv, column 't', line 7: time goes backwards from 5 (line 6) to 4 in segment 'data'; "
        "sort the rows by time",
    ),
    "garbage_numeric": (
        DataError,
        "{dir}/data.csv, column 'T_exh', line 7: 'abc' is not a number; fix or remove the value",
    ),
    "all_nan_column": (
        DataError,
        "{dir}/data.csv, column 'p_lube': every value is missing; remove the column from [columns] or fill it",
    ),
    "empty_file": (DataError, "{dir}/data.csv: the file is empty; it needs a header line and at least 2 data rows"),
    "header_only": (
        DataError,
        "{dir}/data.csv: the file has a header but no data rows; a file needs at least 2 data rows",
    ),
    "one_row": (
        DataError,
        "{dir}/data.csv: only 1 data row (line 2); a file needs at least 2 data rows to form a segment",
    ),
    "huge_value": (
        DataError,
        "{dir}/data.csv, column 'speed', line 4: '1e309' is infinite (outside the float64 range); fix the value",
    ),
    "constant_target": (
        DataError,
        "{dir}/data.csv, column 'T_exh': constant value 300 over the whole file; a constant output carries no "
        "information - remove it from [columns]",
    ),
    "missing_column": (
        DataError,
        "{dir}/data.csv: declared column 'T_cw' is not in the file; the file's columns are 't', 'speed', 'T_exh'",
    ),
    "unknown_role": (
        SpecError,
        "{dir}/spec.toml: column 'speed': unknown role 'inptu'; use one of input, output, internal, group",
    ),
    "short_segment": (
        DataError,
        "{dir}/data.csv: segment 'data#1' (line 6) has 1 row, fewer than min_segment_rows = 2; set "
        "drop_short_segments = true in the spec to drop such segments, or lower min_segment_rows",
    ),
    "off_dt_step": (
        DataError,
        "{dir}/data.csv, column 't', line 5: step of 1.3 s from 2 (line 4) to 3.3 is not a multiple of dt = 1 s; "
        "resample the data to dt or fix dt in the spec",
    ),
    "unknown_spec_key": (
        SpecError,
        "{dir}/spec.toml: unknown key 'license' (did you mean 'licence'?); allowed: " + ALLOWED,
    ),
    "missing_required_key": (
        SpecError,
        "{dir}/spec.toml: missing required key(s) dt; an import spec needs name, dt, files (or [records.NAME] tables) "
        "and a [columns] table",
    ),
    "bad_toml": (SpecError, "{dir}/spec.toml: not valid TOML: Invalid value (at line 4, column 6); fix the spec"),
    "file_not_found": (
        DataError,
        "{dir}/nope.csv: file not found (listed in files of {dir}/spec.toml; paths are relative to the spec)",
    ),
    "missing_value": (DataError, "{dir}/data.csv, column 'speed', line 5: missing value; fill it or remove the row"),
    "extra_field": (
        DataError,
        "{dir}/data.csv, line 4: 4 fields where the header has 3 (a stray delimiter, or decimal commas: then set decimal = \",\" and the file's delimiter); fix the row",
    ),
    "bad_datetime": (
        DataError,
        "{dir}/data.csv, column 't', line 4: 'yesterday' is not an ISO 8601 time stamp; "
        "fix it (e.g. 2024-05-01T12:00:00+00:00)",
    ),
    # keys of published records (no time column, [records.NAME] tables, record column, rate columns)
    "records_unknown_column": (
        SpecError,
        "{dir}/spec.toml: [records.est] columns: 'uu' is not declared in [columns]; did you mean 'u'? the keys are "
        "the spec's column names ('u', 'y'), the values the file's columns",
    ),
    "records_file_not_found": (
        DataError,
        "{dir}/bench.csv: file not found (named in [records.est] of {dir}/spec.toml; paths are relative to the spec)",
    ),
    "records_missing_file_column": (
        DataError,
        "{dir}/data.csv: [records.val] column 'uval' is not in the file; did you mean 'uVal'? (names are "
        "case-sensitive)",
    ),
    "no_time_no_dt": (
        SpecError,
        '{dir}/spec.toml: no time column and no dt; give dt = the sample period in seconds (without time = "COL", '
        "time is the sample index x dt, from 0 in each record)",
    ),
    "fs_disagrees_with_dt": (
        DataError,
        "{dir}/data.csv, column 'Fs', line 2: 400 Hz (a sampling rate: dt = 0.0025 s) disagrees with dt = 0.025 s "
        "in the spec; fix dt (or the value in the file)",
    ),
    "record_starts_again": (
        DataError,
        "{dir}/data.csv, column 'run', line 6: record 'A' starts again after other records (it began on line 2); "
        'give each record its own name, or use segment = "run" to group rows by value',
    ),
    "gap_tolerance_without_time": (
        SpecError,
        "{dir}/spec.toml: gap_tolerance applies to a time column but the spec has no time key; remove gap_tolerance "
        '(time is the sample index x dt) or name the column with time = "COL"',
    ),
    "first_row_only_declared": (
        DataError,
        "{dir}/data.csv, column 'Fs': holds a value only in its first row (100, line 2), like a sampling rate "
        "written once; remove it from [columns] (an undeclared column is dropped with a note)",
    ),
    "rate_column_absent": (
        DataError,
        "{dir}/spec.toml: rate_column 'Samplerate' is in none of the files; did you mean 'SampleRate'? "
        "(names are case-sensitive)",
    ),
}
VALID_CASES = ("gap_split", "short_segment_dropped")


def test_corpus_and_expectations_agree():
    assert sorted(p.name for p in MALFORMED.iterdir()) == sorted([*CASES, *VALID_CASES])


@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_case_gives_its_exact_one_line_message(case):
    kind, expected = CASES[case]
    folder = MALFORMED / case
    with pytest.raises(EngineBenchError) as e:
        import_table(folder / "spec.toml")
    assert type(e.value) is kind
    assert str(e.value) == expected.format(dir=folder)
    assert "\n" not in str(e.value) and "\r" not in str(e.value)


def _csv_rows(case: str) -> pd.DataFrame:
    return pd.read_csv(MALFORMED / case / "data.csv")


def test_gap_splits_a_segment():
    ds = import_table(MALFORMED / "gap_split" / "spec.toml")
    ref = _csv_rows("gap_split")
    assert ds.segment_ids == ["data", "data#1"]
    assert [b - a for _, a, b in ds.segment_bounds()] == [4, 4]
    np.testing.assert_array_equal(ds.frame[TIME].to_numpy(), ref["t"].to_numpy(dtype=float))
    np.testing.assert_array_equal(ds.frame["T_exh"].to_numpy(), ref["T_exh"].to_numpy())


def test_short_segments_can_be_dropped_with_a_warning():
    with pytest.warns(UserWarning, match=r"dropped 1 segment shorter than min_segment_rows = 2 \(1 row\)"):
        ds = import_table(MALFORMED / "short_segment_dropped" / "spec.toml")
    assert ds.segment_ids == ["data", "data#2"]
    assert [b - a for _, a, b in ds.segment_bounds()] == [4, 3]
    assert 10.0 not in set(ds.frame[TIME]) and ds.meta["dropped_segments"] == 1


def test_good_example_matches_a_direct_read():
    ds = import_table(GOOD / "spec.toml")
    runs = [pd.read_csv(GOOD / f) for f in ("run1.csv", "run2.csv")]
    ref = pd.concat(runs, ignore_index=True)
    assert ds.name == "example-engine" and ds.dt == 1.0
    assert ds.segment_ids == ["run1", "run2"]
    assert list(ds.frame.columns) == [SEGMENT, TIME, "speed", "load", "T_amb", "T_exh", "engine"]
    assert ds.schema.inputs == ["speed", "load", "T_amb"] and ds.schema.outputs == ["T_exh"]
    assert ds.schema["load"].unit == "%" and ds.schema.groups == ["engine"]
    for c in ("speed", "load", "T_amb", "T_exh"):
        np.testing.assert_array_equal(ds.frame[c].to_numpy(), ref[c].to_numpy(dtype=float))
    np.testing.assert_array_equal(ds.frame[TIME].to_numpy(), ref["time_s"].to_numpy(dtype=float))
    assert list(ds.frame["engine"]) == list(ref["engine"])
    assert ds.meta["licence"] == "CC0-1.0" and ds.meta["files"] == ["run1.csv", "run2.csv"]


def test_imported_dataset_survives_the_parquet_round_trip(tmp_path):
    ds = import_table(GOOD / "spec.toml")
    back = read_dataset(write_dataset(ds, tmp_path / "good.parquet"))
    pd.testing.assert_frame_equal(back.frame, ds.frame)
    assert back.content_hash() == ds.content_hash() and back.meta == ds.meta


def test_load_spec_resolves_paths_and_defaults():
    spec = load_spec(GOOD / "spec.toml")
    assert isinstance(spec, ImportSpec)
    assert spec.files == (GOOD / "run1.csv", GOOD / "run2.csv")
    assert spec.gap_tolerance == 3.0 and spec.min_segment_rows == 2 and spec.time_unit == "s"
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.dt = 2.0  # type: ignore[misc]
    assert load_spec(MALFORMED / "gap_split" / "spec.toml").gap_tolerance == 1.5


# -- small specs written on the fly -------------------------------------------------------
def write_case(tmp_path: Path, spec: str, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    (tmp_path / "spec.toml").write_text(spec)
    return tmp_path / "spec.toml"


SPEC = """name = "t"
files = {files}
time = "t"
dt = {dt}
{extra}
[columns]
speed = {{ role = "input", unit = "rpm" }}
T_exh = {{ role = "output", unit = "degC" }}
{cols}"""


def spec_text(files=("a.csv",), dt=1.0, extra="", cols="") -> str:
    return SPEC.format(files=json.dumps(list(files)), dt=dt, extra=extra, cols=cols)


@pytest.mark.parametrize(
    "text, message",
    [
        (spec_text().replace('["a.csv"]', '"a.csv"'), "files must be a non-empty list of file names"),
        (spec_text(dt=-1), "dt must be a positive number of seconds, got -1"),
        (spec_text(extra="gap_tolerance = 0.5"), "gap_tolerance = 0.5 s is shorter than dt = 1 s; make it at least dt"),
        (spec_text(extra='time_unit = "us"'), "time_unit 'us' is not one of s, ms, min, h, datetime"),
        (spec_text(cols='t = { role = "input" }'), "the time column 't' must not be declared in [columns]"),
        (spec_text().replace('role = "output", ', 'role = "internal", '), 'no column has role = "output"'),
        (spec_text(cols='x = { role = "input", scale = 2 }'),
         "unknown key of column 'x': 'scale'; allowed: role, unit"),
        (spec_text(extra='delimiter = ";;"'), "delimiter must be one character"),
    ],
)
def test_spec_errors_name_the_spec_and_the_key(tmp_path, text, message):
    path = write_case(tmp_path, text, {"a.csv": "t,speed,T_exh\n0,1,2\n1,2,3\n"})
    with pytest.raises(SpecError) as e:
        load_spec(path)
    assert str(e.value).startswith(f"{path}: ") and message in str(e.value)
    assert "\n" not in str(e.value)


def test_parquet_unit_mismatch_and_adoption(tmp_path):
    table = pa.table(
        {"t": [0.0, 1.0, 2.0], "speed": [600.0, 610.0, 640.0], "T_exh": [300.0, 301.0, 303.5]}
    ).cast(
        pa.schema(
            [
                pa.field("t", pa.float64()),
                pa.field("speed", pa.float64(), metadata={"unit": "rpm"}),
                pa.field("T_exh", pa.float64(), metadata={"unit": "K"}),
            ]
        )
    )
    pq.write_table(table, tmp_path / "a.parquet")
    path = write_case(tmp_path, spec_text(files=("a.parquet",)), {})
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == (
        f"{tmp_path}/a.parquet, column 'T_exh': unit mismatch: the spec says 'degC' but the file records 'K'; "
        "fix the unit in [columns] or convert the column"
    )
    path.write_text(spec_text(files=("a.parquet",)).replace(', unit = "degC"', ""))
    ds = import_table(path)
    assert ds.schema["T_exh"].unit == "K" and ds.schema["speed"].unit == "rpm"
    np.testing.assert_array_equal(ds.frame["T_exh"], [300.0, 301.0, 303.5])


def test_units_recorded_by_enginebench_files_are_checked(tmp_path):
    ds = import_table(GOOD / "spec.toml")
    write_dataset(ds, tmp_path / "eb.parquet")
    text = spec_text(files=("eb.parquet",), extra='segment = "segment"').replace('time = "t"', 'time = "time"')
    path = write_case(tmp_path, text.replace('unit = "rpm"', 'unit = "1/min"'), {})
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == (
        f"{tmp_path}/eb.parquet, column 'speed': unit mismatch: the spec says '1/min' but the file records 'rpm'; "
        "fix the unit in [columns] or convert the column"
    )
    path.write_text(text)
    again = import_table(path)
    assert again.segment_ids == ["run1", "run2"]
    np.testing.assert_array_equal(again.frame["T_exh"], ds.frame["T_exh"])


def test_parquet_timestamps_with_a_zone(tmp_path):
    t = pd.date_range("2024-01-01 01:00", periods=4, freq="2s", tz="Europe/Oslo")
    table = pa.table({"t": t, "speed": [1.0, 2.0, 4.0, 3.0], "T_exh": [5.0, 6.0, 6.5, 7.0]})
    pq.write_table(table, tmp_path / "a.parquet")
    path = write_case(tmp_path, spec_text(files=("a.parquet",), dt=2.0, extra='time_unit = "datetime"'), {})
    ds = import_table(path)
    t0 = datetime(2024, 1, 1, 0, 0, 0, tzinfo=timezone.utc).timestamp()
    np.testing.assert_allclose(ds.frame[TIME].to_numpy(), t0 + 2.0 * np.arange(4), rtol=0, atol=1e-6)
    assert ds.meta["time_zone"] == "Europe/Oslo"
    path.write_text(spec_text(files=("a.parquet",), dt=2.0))
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == (
        f"{tmp_path}/a.parquet, column 't': holds timestamps but time_unit = 's'; set time_unit = \"datetime\""
    )


def test_parquet_rows_are_counted_from_one(tmp_path):
    table = pa.table({"t": [0.0, 1.0, 1.0], "speed": [1.0, 2.0, 3.0], "T_exh": [1.0, 2.0, 4.0]})
    pq.write_table(table, tmp_path / "a.parquet")
    path = write_case(tmp_path, spec_text(files=("a.parquet",)), {})
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == (
        f"{tmp_path}/a.parquet, column 't', rows 2 and 3: duplicate time stamp 1 in segment 'a'; remove the repeated row"
    )


def test_datetime_stamps_become_utc_seconds(tmp_path):
    stamps = ["2024-05-01T14:00:00+02:00", "2024-05-01T14:00:00.5+02:00", "2024-05-01T14:00:01+02:00"]
    csv = "t,speed,T_exh\n" + "".join(f"{s},{600 + i},{300 + i * i}\n" for i, s in enumerate(stamps))
    path = write_case(tmp_path, spec_text(dt=0.5, extra='time_unit = "datetime"'), {"a.csv": csv})
    ds = import_table(path)
    t0 = datetime(2024, 5, 1, 12, 0, 0, tzinfo=timezone.utc).timestamp()
    np.testing.assert_allclose(ds.frame[TIME].to_numpy(), [t0, t0 + 0.5, t0 + 1.0], rtol=0, atol=1e-6)
    assert ds.meta["time_zone"] == "+02:00"


def test_time_offsets_must_agree_across_files(tmp_path):
    a = "t,speed,T_exh\n2024-01-01T00:00:00Z,1,2\n2024-01-01T00:00:01Z,2,3\n"
    b = "t,speed,T_exh\n2024-06-01T00:00:00+02:00,1,2\n2024-06-01T00:00:01+02:00,2,5\n"
    text = spec_text(files=("a.csv", "b.csv"), extra='time_unit = "datetime"')
    path = write_case(tmp_path, text, {"a.csv": a, "b.csv": b})
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == (
        f"{tmp_path}/b.csv, column 't': mixed time zones: this file has offset +02:00, {tmp_path}/a.csv has "
        "offset +00:00; write every stamp with one UTC offset (e.g. all in UTC)"
    )


def test_millisecond_time_and_tab_separated_default(tmp_path):
    tsv = "t\tspeed\tT_exh\n0\t600\t300\n250\t610\t301\n500\t615\t303\n"
    path = write_case(tmp_path, spec_text(files=("a.tsv",), dt=0.25, extra='time_unit = "ms"'), {"a.tsv": tsv})
    ds = import_table(path)
    np.testing.assert_array_equal(ds.frame[TIME].to_numpy(), [0.0, 0.25, 0.5])


def test_segment_column_with_interleaved_rows_keeps_file_lines(tmp_path):
    csv = "voyage,t,speed,T_exh\nB,0,1,10\nA,0,2,11\nB,1,3,12\nA,1,4,13\nB,2,5,14\n"
    text = spec_text(extra='segment = "voyage"', cols='voyage = { role = "group" }')
    path = write_case(tmp_path, text, {"a.csv": csv})
    ds = import_table(path)
    assert ds.segment_ids == ["B", "A"]
    assert list(ds.frame["speed"]) == [1.0, 3.0, 5.0, 2.0, 4.0]
    assert list(ds.frame["voyage"]) == ["B", "B", "B", "A", "A"]
    (tmp_path / "a.csv").write_text(csv.replace("A,1,4,13", "A,0,4,13"))
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == (
        f"{tmp_path}/a.csv, column 't', lines 3 and 5: duplicate time stamp 0 in segment 'A'; remove the repeated row"
    )


def test_constant_is_judged_over_all_files(tmp_path):
    a = "t,speed,T_exh\n0,600,300\n1,600,310\n"
    b = "t,speed,T_exh\n0,700,305\n1,700,306\n"
    path = write_case(tmp_path, spec_text(files=("a.csv", "b.csv")), {"a.csv": a, "b.csv": b})
    ds = import_table(path)  # speed is constant per run but varies across runs: kept
    assert sorted(set(ds.frame["speed"])) == [600.0, 700.0]
    (tmp_path / "b.csv").write_text(b.replace("700", "600"))
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == (
        f"{path}, column 'speed': constant value 600 over all 2 files; a constant input carries no information "
        "- remove it from [columns]"
    )


def test_segment_ids_must_be_unique_across_files(tmp_path):
    (tmp_path / "x").mkdir()
    body = "t,speed,T_exh\n0,600,300\n1,650,310\n"
    path = write_case(tmp_path, spec_text(files=("a.csv", "x/a.csv")), {"a.csv": body, "x/a.csv": body})
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == (
        f"{tmp_path}/x/a.csv: segment 'a' also comes from {tmp_path}/a.csv; segment ids must be unique across "
        "files - rename the file or the segment ids"
    )


# -- validate_frame directly ----------------------------------------------------------------
SCHEMA = Schema.from_roles({"x": "input", "y": "output"})


def frame_at(times: np.ndarray, rng: np.random.Generator) -> pd.DataFrame:
    n = len(times)
    return pd.DataFrame({SEGMENT: "s", "t": times, "x": rng.normal(size=n), "y": rng.normal(size=n)})


def test_dt_tolerance_is_relative():
    rng = np.random.default_rng(3)
    t = np.array([0.0, 1.0, 2.0 + 5e-7, 3.0, 5.0])
    out = validate_frame(frame_at(t, rng), SCHEMA, 1.0, source="f.csv", time_col="t", gap_tolerance=2.5)
    assert list(out[SEGMENT]) == ["s"] * 5  # a 2 dt step within the tolerance is kept, not split
    t[2] = 2.0 + 5e-6
    with pytest.raises(DataError, match=r"line 4: step of 1.000005 s from 1 \(line 3\) to 2.000005"):
        validate_frame(frame_at(t, rng), SCHEMA, 1.0, source="f.csv", time_col="t", gap_tolerance=2.5)


@settings(max_examples=40, deadline=None)
@given(
    steps=st.lists(st.integers(1, 6), min_size=1, max_size=40),
    gap_steps=st.integers(1, 5),
    dt=st.sampled_from([0.1, 1.0, 3.0, 1 / 12]),
)
def test_gap_split_property(steps, gap_steps, dt):
    rng = np.random.default_rng(len(steps))
    ticks = np.r_[0, np.cumsum(steps)]
    frame = frame_at(ticks * dt, rng)
    tol = (gap_steps + 0.5) * dt
    out = validate_frame(frame, SCHEMA, dt, source="f", time_col="t", gap_tolerance=tol, min_segment_rows=1)
    n_gaps = int(np.sum(np.asarray(steps) > gap_steps + 0.5))
    expected = ["s"] + [f"s#{k}" for k in range(1, n_gaps + 1)]
    assert list(pd.unique(out[SEGMENT])) == expected
    np.testing.assert_array_equal(out["y"].to_numpy(), frame["y"].to_numpy())
    np.testing.assert_allclose(out[TIME].to_numpy(), ticks * dt)


def test_validate_frame_returns_dataset_ready_frame():
    rng = np.random.default_rng(4)
    frame = frame_at(np.arange(6.0), rng).astype({"x": str})
    out = validate_frame(frame, SCHEMA, 1.0, source="f.csv", time_col="t", gap_tolerance=1.5)
    ds = Dataset("v", out, SCHEMA, 1.0)
    assert list(ds.frame.columns) == [SEGMENT, TIME, "x", "y"] and ds.frame["x"].dtype == np.float64
    np.testing.assert_allclose(ds.frame["x"], frame["x"].astype(float), rtol=1e-15)


@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_case_at_the_command_line_is_one_line_and_exit_2(case, tmp_path, monkeypatch):
    """`enginebench datasets show SPEC` prints exactly 'error: <message>' and exits with 2."""
    from click.testing import CliRunner

    from enginebench.cli.main import cli

    monkeypatch.setenv("ENGINEBENCH_DATA", str(tmp_path))
    folder = MALFORMED / case
    result = CliRunner().invoke(cli, ["datasets", "show", str(folder / "spec.toml")])
    assert result.exit_code == 2
    assert result.output == f"error: {CASES[case][1].format(dir=folder)}\n"


def test_a_generated_recording_imports_value_for_value_as_pandas_reads_it(tmp_path):
    """Two generated files (20,000 rows x 9 channels each, every digit written, time stamps jittered within the
    tolerance of dt, one gap) import to exactly the numbers pandas.read_csv parses, record by record."""
    rng = np.random.default_rng(11)
    names = [f"ch{i}" for i in range(9)]
    refs = {}
    for rec in ("a", "b"):
        n = 20_000
        t = np.arange(n) * 0.01 + rng.uniform(-1e-9, 1e-9, n)
        if rec == "b":
            t[12_000:] += 0.5  # a gap: the record is split there
        data = rng.normal(size=(n, 9)) * 10.0 ** rng.integers(-3, 4, size=9)
        frame = pd.DataFrame(data, columns=names)
        frame.insert(0, "t", t)
        frame.to_csv(tmp_path / f"{rec}.csv", index=False, float_format="%.17g")
        refs[rec] = pd.read_csv(tmp_path / f"{rec}.csv")
    columns = "\n".join(f'{c} = {{ role = "{"output" if c == "ch0" else "input"}" }}' for c in names)
    (tmp_path / "spec.toml").write_text(f'name = "gen"\nfiles = ["*.csv"]\ntime = "t"\ndt = 0.01\n[columns]\n{columns}\n')
    ds = import_table(tmp_path / "spec.toml")
    assert ds.segment_ids == ["a", "b", "b#1"]
    ref = pd.concat([refs["a"], refs["b"]], ignore_index=True)
    for c in names:
        assert ds.frame[c].to_numpy().tobytes() == ref[c].to_numpy(dtype=np.float64).tobytes()
    assert ds.frame[TIME].to_numpy().tobytes() == ref["t"].to_numpy(dtype=np.float64).tobytes()
