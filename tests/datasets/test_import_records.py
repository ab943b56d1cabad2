"""Import forms of published identification records: no time column, records per file, a record column,
wide [records.NAME] tables, notes on dropped columns, dt checked against a written rate; the built-in
silverbox and f16-gvt importers on the real files (skipped when ../shared/data is absent)."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.datasets.dataset import SEGMENT, TIME
from enginebench.datasets.import_spec import load_spec
from enginebench.datasets.importer import import_table
from enginebench.datasets.io import read_dataset
from enginebench.errors import DataError, SpecError

WIDE = Path(__file__).resolve().parents[1] / "data" / "wide"
SHARED_DATA = Path(os.environ.get("ENGINEBENCH_SHARED", Path(__file__).resolve().parents[2].parent / "shared")) / "data"

COLUMNS = '[columns]\nu = { role = "input", unit = "V" }\ny = { role = "output", unit = "V" }\n'


def write_case(tmp_path: Path, head: str, files: dict[str, str], tail: str = "") -> Path:
    """spec.toml = ``head`` + the u/y [columns] table + ``tail``; ``files`` written beside it."""
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    path = tmp_path / "spec.toml"
    path.write_text('name = "t"\n' + head + "\n" + COLUMNS + tail)
    return path


def column(ds, name: str, segment: str) -> np.ndarray:
    return ds.frame.loc[ds.frame[SEGMENT] == segment, name].to_numpy()


# -- time ---------------------------------------------------------------------------------------
def test_without_a_time_column_time_is_the_index_times_dt_from_zero_in_every_record(tmp_path):
    a = "u,y\n1,2\n2,3\n4,1\n3,0\n5,2\n"
    b = "u,y\n7,1\n6,2\n8,4\n"
    ds = import_table(write_case(tmp_path, 'files = ["a.csv", "b.csv"]\ndt = 0.5', {"a.csv": a, "b.csv": b}))
    assert ds.segment_ids == ["a", "b"] and ds.dt == 0.5
    np.testing.assert_array_equal(column(ds, TIME, "a"), [0.0, 0.5, 1.0, 1.5, 2.0])
    np.testing.assert_array_equal(column(ds, TIME, "b"), [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(column(ds, "u", "a"), [1, 2, 4, 3, 5])
    np.testing.assert_array_equal(column(ds, "y", "b"), [1, 2, 4])
    assert ds.meta["time_unit"] == "index" and "notes" not in ds.meta


def test_time_may_restart_in_every_file(tmp_path):
    a = "t,u,y\n0,1,2\n1,2,3\n2,4,1\n"
    b = "t,u,y\n0,7,1\n1,6,2\n5,8,4\n6,1,1\n"  # a gap of 4 s splits b (gap_tolerance 1.5 s)
    ds = import_table(write_case(tmp_path, 'files = ["a.csv", "b.csv"]\ntime = "t"\ndt = 1.0', {"a.csv": a, "b.csv": b}))
    assert ds.segment_ids == ["a", "b", "b#1"]
    np.testing.assert_array_equal(ds.frame[TIME].to_numpy(), [0, 1, 2, 0, 1, 5, 6])


def test_record_column_cuts_a_file_where_its_value_changes_and_time_restarts(tmp_path):
    text = "run,t,u,y\nest,0,1,2\nest,1,2,3\nest,2,4,1\nval,0,7,1\nval,1,6,2\n"
    head = 'files = ["a.csv"]\ntime = "t"\ndt = 1.0\nrecord = "run"'
    ds = import_table(write_case(tmp_path, head, {"a.csv": text}, 'run = { role = "group" }\n'))
    assert ds.segment_ids == ["est", "val"]
    np.testing.assert_array_equal(ds.frame[TIME].to_numpy(), [0, 1, 2, 0, 1])
    assert list(ds.frame["run"]) == ["est"] * 3 + ["val"] * 2 and ds.schema.groups == ["run"]
    # without a time column (and the record column left undeclared): index x dt from 0 in each record
    (tmp_path / "a.csv").write_text("run,u,y\nest,1,2\nest,2,3\nest,4,1\nval,7,1\nval,6,2\n")
    head = 'files = ["a.csv"]\ndt = 0.1\nrecord = "run"'
    ds = import_table(write_case(tmp_path, head, {}))
    assert ds.segment_ids == ["est", "val"] and "run" not in ds.frame.columns
    np.testing.assert_allclose(ds.frame[TIME].to_numpy(), [0, 0.1, 0.2, 0, 0.1])
    np.testing.assert_array_equal(ds.frame["u"].to_numpy(), [1, 2, 4, 7, 6])


# -- wide files ----------------------------------------------------------------------------------
def test_wide_records_of_equal_length(tmp_path):
    text = "tEst,uEst,yEst,tVal,uVal,yVal\n0,1,2,10,5,6\n1,2,3,11,6,8\n2,4,1,12,7,7\n"
    tail = ('[records.est]\nfile = "w.csv"\ncolumns = { u = "uEst", y = "yEst" }\ntime = "tEst"\n'
            '[records.val]\nfile = "w.csv"\ncolumns = { u = "uVal", y = "yVal" }\ntime = "tVal"\n')
    ds = import_table(write_case(tmp_path, "dt = 1.0", {"w.csv": text}, tail))
    assert ds.segment_ids == ["est", "val"] and list(ds.frame.columns) == [SEGMENT, TIME, "u", "y"]
    np.testing.assert_array_equal(column(ds, "u", "val"), [5, 6, 7])
    np.testing.assert_array_equal(column(ds, TIME, "val"), [10, 11, 12])
    np.testing.assert_array_equal(column(ds, "y", "est"), [2, 3, 1])
    assert ds.meta["records"]["val"] == {"file": "w.csv", "columns": {"u": "uVal", "y": "yVal"}, "time": "tVal"}


def test_wide_records_of_unequal_length_ignore_trailing_blank_cells_and_note_dropped_columns():
    ds = import_table(WIDE / "spec.toml")
    with open(WIDE / "bench.csv", newline="") as fh:
        rows = list(csv.reader(fh))[1:]
    est = np.array([[float(r[0]), float(r[1])] for r in rows])
    val = np.array([[float(r[2]), float(r[3])] for r in rows if r[2]])
    assert ds.segment_ids == ["estimation", "test"] and len(est) == 12 and len(val) == 8
    np.testing.assert_array_equal(column(ds, "u", "estimation"), est[:, 0])
    np.testing.assert_array_equal(column(ds, "y", "test"), val[:, 1])
    np.testing.assert_allclose(column(ds, TIME, "test"), 0.001 * np.arange(8))
    assert ds.meta["notes"] == [
        "bench.csv: column 'fs' holds a value only in its first row (1000, line 2); dropped "
        "(fs = 1000 Hz agrees with dt = 0.001 s)",
        "bench.csv: column 6 (no name, after the delimiter that ends every line) is empty on every line; dropped",
    ]


def test_a_blank_cell_inside_a_wide_record_names_the_file_column_and_line(tmp_path):
    text = "uEst,yEst,uVal,yVal\n1,2,5,6\n2,,6,8\n4,1,,\n3,3,,\n"
    tail = ('[records.est]\nfile = "w.csv"\ncolumns = { u = "uEst", y = "yEst" }\n'
            '[records.val]\nfile = "w.csv"\ncolumns = { u = "uVal", y = "yVal" }\n')
    path = write_case(tmp_path, "dt = 1.0", {"w.csv": text}, tail)
    with pytest.raises(DataError) as e:
        import_table(path)
    assert str(e.value) == f"{tmp_path}/w.csv, column 'yEst', line 3: missing value; fill it or remove the row"


def test_files_and_record_tables_together_and_a_one_row_record(tmp_path):
    tail = '[records.w]\nfile = "w.csv"\ncolumns = { u = "a", y = "b" }\n'
    files = {"r.csv": "u,y\n1,2\n2,1\n", "w.csv": "a,b,c,d\n1,2,3,4\n2,5,6,1\n"}
    ds = import_table(write_case(tmp_path, 'files = ["r.csv"]\ndt = 1.0', files, tail))
    assert ds.segment_ids == ["r", "w"] and ds.meta["files"] == ["r.csv", "w.csv"]
    (tmp_path / "w.csv").write_text("a,b\n1,2\n,\n")
    with pytest.raises(DataError) as e:
        import_table(tmp_path / "spec.toml")
    assert str(e.value) == (
        f"{tmp_path}/w.csv: record 'w' has only 1 data row (line 2); a record needs at least 2 data rows"
    )


# -- dropped columns and the sampling rate ---------------------------------------------------------
def test_empty_columns_are_dropped_with_a_note(tmp_path):
    text = "u,,y,spare\n1,,2,\n2,,3,\n4,,1,\n"
    ds = import_table(write_case(tmp_path, 'files = ["a.csv"]\ndt = 1.0', {"a.csv": text}))
    assert list(ds.frame.columns) == [SEGMENT, TIME, "u", "y"]
    assert ds.meta["notes"] == [
        "a.csv: column 2 (no name) is empty on every line; dropped",
        "a.csv: column 'spare' is empty on every line; dropped",
    ]


def test_a_value_in_the_first_row_only_is_dropped_with_its_value(tmp_path):
    text = "u,y,Comment\n1,2,bench B 2024\n2,3,\n4,1,\n"
    ds = import_table(write_case(tmp_path, 'files = ["a.csv"]\ndt = 1.0', {"a.csv": text}))
    assert ds.meta["notes"] == ["a.csv: column 'Comment' holds a value only in its first row (bench B 2024, line 2); dropped"]
    np.testing.assert_array_equal(ds.frame["u"].to_numpy(), [1, 2, 4])


def test_undeclared_columns_with_data_are_ignored_silently(tmp_path):
    text = "u,y,other\n1,2,5\n2,3,\n4,1,7\n"
    ds = import_table(write_case(tmp_path, 'files = ["a.csv"]\ndt = 1.0', {"a.csv": text}))
    assert "notes" not in ds.meta and list(ds.frame.columns) == [SEGMENT, TIME, "u", "y"]


AGREE = [
    ("Fs", "400", "0.0025", "Fs = 400 Hz agrees with dt = 0.0025 s"),
    ("fs", "610.35", str(2**14 / 1e7), "fs = 610.35 Hz agrees with dt = 0.0016384 s"),  # as written: +-0.005 Hz
    ("Ts", "0.0025", "0.0025", "Ts = 0.0025 s agrees with dt = 0.0025 s"),
    ("ts", "2", "2.0", "ts = 2 s agrees with dt = 2 s"),
]


@pytest.mark.parametrize("name, value, dt, agreement", AGREE)
def test_a_rate_or_period_written_once_agrees_with_dt(tmp_path, name, value, dt, agreement):
    text = f"u,y,{name},\n1,2,{value},\n2,3,,\n4,1,,\n"
    ds = import_table(write_case(tmp_path, f'files = ["a.csv"]\ndt = {dt}', {"a.csv": text}))
    assert ds.meta["notes"][0] == (
        f"a.csv: column {name!r} holds a value only in its first row ({value}, line 2); dropped ({agreement})"
    )


DISAGREE = [
    ("Fs", "610.35", "0.001639344262295082",  # dt = 1/610 s
     "610.35 Hz (a sampling rate: dt = 0.001638404194 s) disagrees with dt = 0.001639344262 s"),
    ("Ts", "0.01", "0.001", "0.01 s (a sample period) disagrees with dt = 0.001 s"),
]


@pytest.mark.parametrize("name, value, dt, message", DISAGREE)
def test_a_rate_or_period_that_disagrees_with_dt_is_one_error_line(tmp_path, name, value, dt, message):
    text = f"u,y,{name}\n1,2,{value}\n2,3,\n4,1,\n"
    with pytest.raises(DataError) as e:
        import_table(write_case(tmp_path, f'files = ["a.csv"]\ndt = {dt}', {"a.csv": text}))
    assert str(e.value) == f"{tmp_path}/a.csv, column {name!r}, line 2: {message} in the spec; fix dt (or the value in the file)"


def test_rate_and_period_columns_named_in_the_spec(tmp_path):
    text = "u,y,SampleRate,Step\n1,2,100,0.01\n2,3,100,0.01\n4,1,100,0.01\n"
    head = 'files = ["a.csv"]\ndt = 0.01\nrate_column = "SampleRate"\nperiod_column = "Step"'
    ds = import_table(write_case(tmp_path, head, {"a.csv": text}))
    assert ds.meta["notes"] == [
        "a.csv: column 'SampleRate' holds 100 on every filled line; not imported "
        "(SampleRate = 100 Hz agrees with dt = 0.01 s)",
        "a.csv: column 'Step' holds 0.01 on every filled line; not imported (Step = 0.01 s agrees with dt = 0.01 s)",
    ]
    (tmp_path / "a.csv").write_text(text.replace("2,3,100", "2,3,200"))
    with pytest.raises(DataError) as e:
        import_table(tmp_path / "spec.toml")
    assert str(e.value) == (
        f"{tmp_path}/a.csv, column 'SampleRate': holds 2 different values (100, 200, ...); the rate column must "
        "hold one value"
    )
    (tmp_path / "a.csv").write_text("u,y,SampleRate,Step\n1,2,50,0.01\n2,3,,\n4,1,,\n")
    with pytest.raises(DataError) as e:
        import_table(tmp_path / "spec.toml")
    assert str(e.value) == (
        f"{tmp_path}/a.csv, column 'SampleRate', line 2: 50 Hz (a sampling rate: dt = 0.02 s) disagrees with "
        "dt = 0.01 s in the spec; fix dt (or the value in the file)"
    )


# -- spec mistakes around the new keys --------------------------------------------------------------
@pytest.mark.parametrize(
    "head, tail, message",
    [
        ('files = ["a.csv"]\ndt = 1.0\nrecord = "run"\nsegment = "run"', "",
         'segment and record are both given; use record = "COL" (a new record where the value changes) or '
         'segment = "COL" (rows grouped by value), not both'),
        ("dt = 1.0", "[records]\n", "records must hold [records.NAME] tables"),
        ("dt = 1.0", '[records.est]\ncolumns = { u = "uEst" }\n',
         '[records.est] needs file = "..." (the file holding its columns), got None'),
        ("dt = 1.0", '[records.est]\nfile = "a.csv"\ncolums = { u = "x" }\n',
         "unknown key of [records.est]: 'colums' (did you mean 'columns'?); allowed: file, columns, time"),
        ('files = ["a.csv"]\ndt = 1.0', '[records.a]\nfile = "b.csv"\n',
         "[records.a] has the name of the record of file 'a.csv' in files; rename the [records] table"),
        ('files = ["a.csv"]\ndt = 1.0', '[records.b]\nfile = "a.csv"\n',
         "[records.b] reads 'a.csv', which files also lists as a record of its own"),
        ('files = ["a.csv"]\ndt = 1.0\nrate_column = "u"', "",
         "rate_column 'u' is also a column the import reads"),
        ('files = ["a.csv"]\ndt = 1.0\ntime_unit = "ms"', "", "time_unit applies to a time column"),
        ('dt = 1.0', "", "missing required key(s) files; an import spec needs name, dt, files (or [records.NAME] "
                         "tables) and a [columns] table"),
        ('dt = 1.0\nrecord = "run"', '[records.b]\nfile = "a.csv"\n',
         "record = 'run' names records inside the files of files = [...], but there are none"),
    ],
)
def test_spec_mistakes_with_records_are_one_line(tmp_path, head, tail, message):
    path = write_case(tmp_path, head, {"a.csv": "u,y\n1,2\n2,3\n"}, tail)
    with pytest.raises(SpecError) as e:
        load_spec(path)
    assert str(e.value).startswith(f"{path}: ") and message in str(e.value), str(e.value)
    assert "\n" not in str(e.value)


# -- the command line -----------------------------------------------------------------------------
def test_datasets_import_and_show_print_records_and_notes(tmp_path, monkeypatch):
    monkeypatch.setenv("ENGINEBENCH_DATA", str(tmp_path / "home"))
    runner = CliRunner()
    spec = str(WIDE / "spec.toml")
    out = runner.invoke(cli, ["datasets", "import", spec])
    assert out.exit_code == 0, out.output
    lines = out.output.splitlines()
    assert lines[0] == "read wide-bench: 20 rows in 2 segment(s), dt = 0.001 s (nothing written: experiments read the spec itself)"
    assert lines[1:3] == ["  estimation: 12 rows, 0.012 s", "  test: 8 rows, 0.008 s"]
    assert lines[3:] == [f"note: {n}" for n in import_table(spec).meta["notes"]]
    target = tmp_path / "wide.parquet"
    out = runner.invoke(cli, ["datasets", "import", spec, "--output", str(target)])
    assert out.exit_code == 0 and out.output.startswith(f"imported wide-bench: 20 rows in 2 segment(s), dt = 0.001 s -> {target}")
    back = read_dataset(target)
    pd.testing.assert_frame_equal(back.frame, import_table(spec).frame)
    shown = runner.invoke(cli, ["datasets", "show", str(target)])
    assert shown.exit_code == 0 and "records:\n  estimation: 12 rows, 0.012 s\n" in shown.output
    assert shown.output.endswith("".join(f"note: {n}\n" for n in back.meta["notes"]))
    bad = runner.invoke(cli, ["datasets", "import", spec, "--from", "x"])
    assert bad.exit_code == 2 and bad.output == f"error: {spec}: --from is for built-in datasets; a spec names its own files\n"


def test_builtin_import_needs_the_folder_with_the_files(tmp_path, monkeypatch):
    monkeypatch.setenv("ENGINEBENCH_DATA", str(tmp_path / "home"))
    runner = CliRunner()
    out = runner.invoke(cli, ["datasets", "import", "silverbox"])
    assert out.exit_code == 2 and out.output == (
        "error: dataset 'silverbox' is imported from your copy of its files: give --from DIR (enginebench datasets "
        "import silverbox --from DIR (the folder with SNLS80mV.csv))\n"
    )
    out = runner.invoke(cli, ["datasets", "import", "f16-gvt", "--from", str(tmp_path)])
    assert out.exit_code == 2 and out.output == (
        f"error: {tmp_path}/F16Data_FullMSine_Level1.csv: file not found; the f16-gvt import needs "
        "F16Data_FullMSine_Level1.csv, F16Data_FullMSine_Level2_Validation.csv, F16Data_FullMSine_Level3.csv, "
        "F16Data_FullMSine_Level4_Validation.csv in the folder given to --from (as the benchmark collection "
        "distributes them)\n"
    )


# -- the real published records -------------------------------------------------------------------
def _shared(name: str) -> Path:
    folder = SHARED_DATA / name
    if not folder.is_dir():
        pytest.skip(f"shared data not found at {folder} (set ENGINEBENCH_SHARED)")
    return folder


@pytest.fixture(scope="module")
def silverbox():
    from enginebench.datasets.sysid_benchmarks import import_silverbox

    return import_silverbox(_shared("silverbox"))


@pytest.fixture(scope="module")
def f16():
    from enginebench.datasets.sysid_benchmarks import import_f16

    return import_f16(_shared("f16-gvt"))


def _file_rows(path: Path, rows: list[int]) -> list[list[str]]:
    """The given data rows (0 = first after the header, -1 = the last) as the csv module reads them."""
    first, last = [], None
    with open(path, newline="") as fh:
        for i, row in enumerate(csv.reader(fh)):
            if i and row:
                if i - 1 < 2:
                    first.append(row)
                last = row
    return [last if i == -1 else first[i] for i in rows]


@pytest.mark.shared_data
def test_silverbox_record_as_published(silverbox):
    ds = silverbox
    assert ds.name == "silverbox" and ds.segment_ids == ["SNLS80mV"] and len(ds) == 131072
    assert ds.dt == 2**14 / 1e7 == 0.0016384
    assert ds.schema.inputs == ["V1"] and ds.schema.outputs == ["V2"] and ds.schema["V2"].unit == "V"
    assert ds.frame[TIME].iloc[-1] == pytest.approx(131071 * 0.0016384, rel=1e-12)
    first, last = _file_rows(SHARED_DATA / "silverbox" / "SNLS80mV.csv", [0, -1])
    assert ds.frame[["V1", "V2"]].iloc[0].tolist() == [float(first[0]), float(first[1])] == [0.0057756, 0.0093978]
    assert ds.frame[["V1", "V2"]].iloc[-1].tolist() == [float(last[0]), float(last[1])]
    assert ds.meta["notes"] == [
        "SNLS80mV.csv: column 3 (no name, after the delimiter that ends every line) is empty on every line; dropped"
    ]
    assert "Wigren" in ds.meta["citation"] and ds.meta["synthetic"] is False


@pytest.mark.shared_data
def test_f16_records_as_published(f16):
    ds = f16
    stems = ["F16Data_FullMSine_Level1", "F16Data_FullMSine_Level2_Validation", "F16Data_FullMSine_Level3",
             "F16Data_FullMSine_Level4_Validation"]
    assert ds.segment_ids == stems and [b - a for _, a, b in ds.segment_bounds()] == [73728] * 4
    assert ds.dt == 0.0025 and ds.schema.inputs == ["Force"] and ds.schema.internals == ["Voltage"]
    assert ds.schema.outputs == ["Acceleration1", "Acceleration2", "Acceleration3"]
    assert ds.schema["Acceleration2"].unit == "m/s^2" and ds.schema["Force"].unit == "N"
    np.testing.assert_allclose(column(ds, TIME, stems[2])[[0, 1, -1]], [0.0, 0.0025, 73727 * 0.0025], rtol=1e-12)
    for stem in (stems[0], stems[3]):
        first, second = _file_rows(SHARED_DATA / "f16-gvt" / f"{stem}.csv", [0, 1])
        got = ds.frame.loc[ds.frame[SEGMENT] == stem, ["Force", "Voltage", "Acceleration1", "Acceleration2",
                                                      "Acceleration3"]].iloc[:2].to_numpy()
        np.testing.assert_array_equal(got, [[float(v) for v in first[:5]], [float(v) for v in second[:5]]])
    assert ds.frame.loc[0, "Force"] == 0.95714
    notes = ds.meta["notes"]
    assert len(notes) == 8 and notes[0] == (
        "F16Data_FullMSine_Level1.csv: column 'Fs' holds a value only in its first row (400, line 2); dropped "
        "(Fs = 400 Hz agrees with dt = 0.0025 s)"
    )
    assert ds.meta["published_split"] == {"train": [stems[0], stems[2]], "test": [stems[1], stems[3]]}


@pytest.mark.shared_data
def test_silverbox_through_the_command_line(tmp_path, monkeypatch):
    folder = _shared("silverbox")
    monkeypatch.setenv("ENGINEBENCH_DATA", str(tmp_path))
    runner = CliRunner()
    out = runner.invoke(cli, ["datasets", "import", "silverbox", "--from", str(folder)])
    assert out.exit_code == 0, out.output
    assert out.output.splitlines()[0] == f"imported silverbox: 131072 rows in 1 segment(s) -> {tmp_path}/silverbox.parquet"
    shown = runner.invoke(cli, ["datasets", "show", "silverbox"])
    assert shown.exit_code == 0
    assert shown.output.startswith("silverbox: 131072 rows in 1 segment(s), dt = 0.0016384 s, 3.6 min\n")
    assert "  SNLS80mV: 131072 rows, 3.6 min\n" in shown.output and "note: SNLS80mV.csv: column 3" in shown.output
