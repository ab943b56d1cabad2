"""Long recordings are parsed by pyarrow's CSV reader (issue 34, item 3): value for value what pandas.read_csv
gives, and pandas still reads (and reports on) every file pyarrow cannot take as it is."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets import readers
from enginebench.datasets.importer import import_table
from enginebench.errors import DataError


def pandas_reference(path, n_fields, text_pos, header_row=True):
    return pd.read_csv(path, sep=",", header=0 if header_row else None, names=[f"c{i}" for i in range(n_fields)],
                       index_col=False, dtype={f"c{i}": str for i in text_pos}, skip_blank_lines=False,
                       encoding="utf-8-sig")


@pytest.fixture
def generated(tmp_path):
    """A recording: time, floats over ten decades written with every digit, integers, text with NA cells."""
    rng = np.random.default_rng(3)
    n = 20_000
    frame = pd.DataFrame({"t": np.arange(n) * 0.01, "a": rng.normal(size=n) * 10.0 ** rng.integers(-5, 6, n),
                          "i": rng.integers(-1000, 1000, n), "s": rng.choice(["x", "y z", "NA", ""], n),
                          "b": rng.normal(size=n), "e": rng.normal(size=n).round(3)})
    frame.loc[5, "b"] = np.nan
    frame.loc[7, "e"] = 1e300
    path = tmp_path / "rec.csv"
    frame.to_csv(path, index=False)
    return path


def test_arrow_frame_equals_pandas_value_for_value(generated):
    fast = readers._parse_csv_arrow(generated, ",", 6, [3], header_row=True)
    assert fast is not None
    pd.testing.assert_frame_equal(fast, pandas_reference(generated, 6, [3]), check_exact=True)
    headerless = generated.with_name("bare.csv")
    headerless.write_text(generated.read_text().split("\n", 1)[1])
    fast = readers._parse_csv_arrow(headerless, ",", 6, [3], header_row=False)
    pd.testing.assert_frame_equal(fast, pandas_reference(headerless, 6, [3], header_row=False), check_exact=True)


@pytest.mark.parametrize("line, by_arrow", [
    ("1.0,2.0,3.0,4.0", False),  # a row with another number of fields: pandas reads it and names the line
    ("", True),                  # a blank line: a row of NaN from both (reported with its line later)
    ("1.0,x,2.0", False),        # text in a number column: pandas keeps it for parse_numbers to report
    ("1.0,None,2.0", True),      # a missing-value text pandas knows: NaN from both
    ("1.0,,-inf", True),
])
def test_what_arrow_cannot_take_as_it_is_goes_to_pandas(tmp_path, line, by_arrow):
    path = tmp_path / "odd.csv"
    path.write_text("a,b,c\n" + "1.5,2.5,3.5\n" * 50 + line + "\n" + "1.5,2.5,3.5\n" * 50)
    fast = readers._parse_csv_arrow(path, ",", 3, [], header_row=True)
    assert (fast is not None) == by_arrow
    if by_arrow:
        pd.testing.assert_frame_equal(fast, pandas_reference(path, 3, []), check_exact=True)


def write_spec(folder, name):
    (folder / f"{name}.toml").write_text(
        f'name = "{name}"\nfiles = ["rec.csv"]\ntime = "t"\ndt = 0.01\n[columns]\n'
        'a = { role = "input", unit = "V" }\ni = { role = "input" }\ne = { role = "input" }\n'
        'b = { role = "output", unit = "degC" }\n', encoding="utf-8")
    return folder / f"{name}.toml"


def test_an_import_through_arrow_equals_the_import_through_pandas(generated, monkeypatch):
    frame = pd.read_csv(generated)
    frame.loc[5, "b"] = 0.5  # the output must be complete
    frame.to_csv(generated, index=False)
    spec = write_spec(generated.parent, "rec")
    calls = []
    real = readers._parse_csv_arrow
    monkeypatch.setattr(readers, "_parse_csv_arrow", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(readers, "ARROW_MIN_BYTES", 0)
    fast = import_table(spec)
    monkeypatch.setattr(readers, "ARROW_MIN_BYTES", 1 << 62)
    slow = import_table(spec)
    assert len(calls) == 1
    pd.testing.assert_frame_equal(fast.frame, slow.frame, check_exact=True)
    assert fast.content_hash() == slow.content_hash()


def test_a_bad_cell_is_reported_with_its_line_on_the_arrow_path(tmp_path, monkeypatch):
    monkeypatch.setattr(readers, "ARROW_MIN_BYTES", 0)
    rows = [f"{k * 0.01:.2f},{k},1,{k % 7}" for k in range(40)]
    rows[20] = "0.20,20,1,3,5"  # one field too many: pandas' error names the line
    (tmp_path / "rec.csv").write_text("t,a,i,b\n" + "\n".join(rows) + "\n")
    (tmp_path / "rec.toml").write_text('name = "rec"\nfiles = ["rec.csv"]\ntime = "t"\ndt = 0.01\n[columns]\n'
                                       'a = { role = "input" }\ni = { role = "input" }\nb = { role = "output" }\n')
    with pytest.raises(DataError, match=r"rec.csv, line 22: 5 fields where the header has 4"):
        import_table(tmp_path / "rec.toml")
