"""Files without a header row, as engine test benches and data publishers write them: fields named by
position (the [columns] order, ``names``, or a record's field list), many files by a glob, and the built-in
bosch-gengine2 importer on the real campaign (skipped when ../shared/data is absent)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT
from enginebench.datasets.importer import import_table
from enginebench.errors import DataError, SpecError

SHARED_DATA = Path(os.environ.get("ENGINEBENCH_SHARED", Path(__file__).resolve().parents[2].parent / "shared")) / "data"
GENGINE2 = SHARED_DATA / "bosch-gengine2"
COLUMNS = ('[columns]\nspeed = { role = "input", unit = "rpm" }\nload = { role = "input" }\n'
           'nox = { role = "output", unit = "ppm" }\n')


def write(tmp_path: Path, head: str, files: dict[str, str], columns: str = COLUMNS) -> Path:
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    path = tmp_path / "spec.toml"
    path.write_text('name = "bench"\ndt = 0.1\n' + head + "\n" + columns)
    return path


def column(ds, name: str, segment: str) -> np.ndarray:
    return ds.frame.loc[ds.frame[SEGMENT] == segment, name].to_numpy()


def test_fields_are_named_in_the_columns_order_and_read_back_exactly(tmp_path):
    rng = np.random.default_rng(0)
    data = rng.standard_normal((50, 3))
    text = "\n".join(",".join(repr(float(v)) for v in row) for row in data) + "\n"
    ds = import_table(write(tmp_path, 'header = false\nfiles = ["run1.csv"]', {"run1.csv": text}))
    assert ds.segment_ids == ["run1"] and len(ds.frame) == 50  # the first line is data, not a header
    for j, name in enumerate(("speed", "load", "nox")):
        np.testing.assert_array_equal(column(ds, name, "run1"), data[:, j])
    assert ds.schema["speed"].unit == "rpm"


def test_names_list_every_field_and_skip_the_empty_ones(tmp_path):
    text = "9,1,2,3\n9,4,5,6\n9,7,8,9\n"
    spec = write(tmp_path, 'header = false\nfiles = ["a.csv"]\nnames = ["", "nox", "speed", "load"]', {"a.csv": text})
    ds = import_table(spec)
    np.testing.assert_array_equal(column(ds, "nox", "a"), [1, 4, 7])
    np.testing.assert_array_equal(column(ds, "speed", "a"), [2, 5, 8])
    np.testing.assert_array_equal(column(ds, "load", "a"), [3, 6, 9])


def test_a_glob_reads_many_files_as_records_in_sorted_order(tmp_path):
    files = {f"raw_{i:02d}.csv": f"{i},1,{i * 2}\n{i + 1},0,{i * 3}\n{i + 2},1,{i}\n" for i in (3, 1, 12)}
    files["other.csv"] = "1,1,1\n2,2,2\n"
    ds = import_table(write(tmp_path, 'header = false\nfiles = ["raw_*.csv"]', files))
    assert ds.segment_ids == ["raw_01", "raw_03", "raw_12"]
    np.testing.assert_array_equal(column(ds, "nox", "raw_12"), [24, 36, 12])


def test_records_tables_list_their_fields_in_file_order(tmp_path):
    text = "1,10,100,2,20,200\n3,30,300,4,40,400\n5,50,500,6,60,600\n"
    head = ('[records.est]\nfile = "w.csv"\ncolumns = ["speed", "load", "nox", "", "", ""]\n'
            '[records.val]\nfile = "w.csv"\ncolumns = ["", "", "", "speed", "load", "nox"]\n')
    path = tmp_path / "spec.toml"
    (tmp_path / "w.csv").write_text(text)
    path.write_text('name = "bench"\ndt = 0.1\nheader = false\n' + COLUMNS + head)
    ds = import_table(path)
    assert ds.segment_ids == ["est", "val"]
    np.testing.assert_array_equal(column(ds, "nox", "est"), [100, 300, 500])
    np.testing.assert_array_equal(column(ds, "speed", "val"), [2, 4, 6])


def test_records_tables_of_headerless_files_read_the_columns_order(tmp_path):
    path = tmp_path / "spec.toml"
    (tmp_path / "m1.csv").write_text("1,2,3\n4,5,6\n")
    (tmp_path / "m2.csv").write_text("7,8,9\n1,2,3\n")
    path.write_text('name = "b"\ndt = 1.0\nheader = false\n' + COLUMNS
                    + '[records.first]\nfile = "m1.csv"\n[records.second]\nfile = "m2.csv"\n')
    ds = import_table(path)
    np.testing.assert_array_equal(column(ds, "load", "second"), [8, 2])


@pytest.mark.parametrize("head, files, message", [
    ('files = ["a.csv"]', {"a.csv": "1,2,3\n4,5,6\n"},
     r"a.csv, line 1: holds numbers \(1, 2, 3\), not column names: the file has no header row; set header = false"),
    ('header = false\nfiles = ["a.csv"]', {"a.csv": "1,2\n4,5\n"},
     r"a.csv, line 1: 2 fields, but with header = false declared column 'nox' is field 3"),
    ('header = false\nfiles = ["raw_*.csv"]', {"a.csv": "1,2,3\n"},
     r"files pattern 'raw_\*.csv' matches no file in"),
    ('files = ["a.csv"]\nnames = ["speed", "load", "nox"]', {"a.csv": "speed,load,nox\n1,2,3\n4,5,6\n"},
     r"names applies to files without a header row; add header = false"),
    ('header = false\nfiles = ["a.csv"]\nnames = ["speed", "speed", "nox"]', {"a.csv": "1,2,3\n"},
     r"names lists 'speed' twice"),
    ('header = false\nfiles = ["a.csv"]\ntime = "t"', {"a.csv": "0,1,2,3\n"},
     r"header = false with time = 't': give names = \[...\] with every field of the files in order"),
    ('header = false\nfiles = ["a.csv"]\nnames = ["speed", "nox"]', {"a.csv": "1,2\n"},
     r"names has no field 'load'"),
])
def test_mistakes_are_one_line_errors(tmp_path, head, files, message):
    with pytest.raises((DataError, SpecError), match=message):
        import_table(write(tmp_path, head, files))


def test_a_record_field_list_needs_header_false(tmp_path):
    path = tmp_path / "spec.toml"
    (tmp_path / "w.csv").write_text("speed,load,nox\n1,2,3\n4,5,6\n")
    path.write_text('name = "b"\ndt = 1.0\n' + COLUMNS + '[records.a]\nfile = "w.csv"\ncolumns = ["speed", "load", "nox"]\n')
    with pytest.raises(SpecError, match=r"\[records.a\] columns is a list of fields in file order, which needs header = false"):
        import_table(path)


@pytest.mark.shared_data
def test_the_built_in_gengine2_import_reads_every_measurement_as_published(tmp_path):
    if not GENGINE2.is_dir():
        pytest.skip(f"bosch-gengine2 not found at {GENGINE2} (set ENGINEBENCH_SHARED)")
    from enginebench.datasets.bosch_engine import import_gengine2

    ds = import_gengine2(GENGINE2)
    assert ds.dt == 0.1 and len(ds.frame) == 231_867
    assert ds.schema.inputs == ["speed", "load", "lambda", "ignition"]
    assert ds.schema.outputs == ["pn", "hc", "nox", "t_manifold", "t_cat"]
    split = ds.meta["published_split"]
    assert split["test"] == ["m17", "m19", "m21"] and split["train"][0] == "m01" and len(split["train"]) == 10
    raw = pd.read_csv(GENGINE2 / "raw_000019_measurement_000000.csv", header=None).to_numpy()
    got = ds.frame.loc[ds.frame[SEGMENT] == "m19", ["speed", "load", "lambda", "ignition", "pn", "hc", "nox",
                                                  "t_manifold", "t_cat"]].to_numpy()
    np.testing.assert_array_equal(got, raw)
    assert "CC BY-SA 4.0" in ds.meta["licence"]


def test_the_gengine2_import_needs_both_sides_of_the_split(tmp_path):
    from enginebench.datasets.bosch_engine import import_gengine2

    (tmp_path / "raw_000001_measurement_000000.csv").write_text("0,0,0,0,0,0,0,0,0\n1,1,1,1,1,1,1,1,1\n")
    with pytest.raises(DataError, match=r"needs measurements of both sides of the publisher's split .* found "
                                        r"raw_000001_measurement_000000.csv"):
        import_gengine2(tmp_path)


def test_a_records_table_may_not_read_the_target_from_an_input_column(tmp_path):
    path = tmp_path / "spec.toml"
    (tmp_path / "w.csv").write_text("a,b,c\n1,2,3\n4,5,6\n")
    path.write_text('name = "b"\ndt = 1.0\n' + COLUMNS + '[records.r]\nfile = "w.csv"\n'
                    'columns = { speed = "a", load = "b", nox = "a" }\n')
    with pytest.raises(SpecError, match=r"\[records.r\]: file column 'a' is read as 'speed', 'nox'; a target read from "
                                        r"the same column as another signal leaks it"):
        import_table(path)


def test_whitespace_separated_files_with_or_without_a_header(tmp_path):
    (tmp_path / "log.dat").write_text("  1.5   2   3\n 4\t5    6e1\n7 8 9\n")
    spec = write(tmp_path, 'header = false\nfiles = ["log.dat"]\ndelimiter = "whitespace"', {})
    ds = import_table(spec)
    np.testing.assert_array_equal(column(ds, "nox", "log"), [3.0, 60.0, 9.0])
    np.testing.assert_array_equal(column(ds, "speed", "log"), [1.5, 4.0, 7.0])
    (tmp_path / "h.txt").write_text("speed   load  nox\n1 2 3\n4  5   6\n")
    ds = import_table(write(tmp_path, 'files = ["h.txt"]\ndelimiter = "whitespace"', {}))
    np.testing.assert_array_equal(column(ds, "load", "h"), [2.0, 5.0])


def test_the_built_in_gengine1_import_reads_its_thirteen_fields_and_the_published_split(tmp_path):
    """gengine1 as its publisher distributes it (headerless, 13 fields), here generated: measurements 10 and 31 are
    training, 53 test, 40 outside the split (left out with a note)."""
    from enginebench.datasets.bosch_engine import GENGINE1, import_gengine1

    rng = np.random.default_rng(0)
    written = {}
    for n in (10, 31, 53, 40):
        data = rng.standard_normal((30, 13))
        (tmp_path / f"raw_{n:06d}_measurement_000000.csv").write_text(
            "\n".join(",".join(f"{v:.8e}" for v in row) for row in data) + "\n")
        written[n] = data
    ds = import_gengine1(tmp_path)
    assert ds.schema.inputs == ["speed", "load", "lambda", "ignition", "fuel_cutoff"]
    assert ds.schema.outputs == ["pn", "co", "co2", "hc", "nox", "o2", "t_manifold", "t_cat"]
    assert ds.meta["published_split"] == {"train": ["m10", "m31"], "test": ["m53"]}
    assert ds.segment_ids == ["m10", "m31", "m53"]
    got = ds.frame.loc[ds.frame[SEGMENT] == "m31", [name for name, _ in GENGINE1.fields]].to_numpy()
    np.testing.assert_allclose(got, written[31], rtol=1e-8)
    assert ds.meta["notes"][-1] == "1 file(s) outside the publisher's split left out: raw_000040_measurement_000000.csv"
    assert "gengine1" in ds.meta["licence"]
