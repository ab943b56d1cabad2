"""Files as test-bench software exports them in much of Europe: a decimal comma (with a semicolon or a tab
between fields) and a units row under the header, read unmodified through ``decimal`` and ``units_row``;
left undeclared, each is one error line saying which key to set."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from enginebench.datasets.dataset import SEGMENT
from enginebench.datasets.importer import import_table
from enginebench.errors import DataError, SpecError

COLUMNS = '[columns]\nspeed = { role = "input", unit = "rpm" }\nT_exh = { role = "output" }\n'


def write(tmp_path: Path, head: str, text: str, name: str = "run.csv") -> Path:
    (tmp_path / name).write_text(text)
    path = tmp_path / "spec.toml"
    path.write_text(f'name = "bench"\ndt = 0.1\nfiles = ["{name}"]\ntime = "t"\n{head}\n{COLUMNS}')
    return path


def table(rows: np.ndarray, sep: str, decimal: str, units: str | None = None) -> str:
    lines = [sep.join(("t", "speed", "T_exh"))]
    if units is not None:
        lines.append(units)
    for row in rows:
        lines.append(sep.join(f"{v:.6f}".replace(".", decimal) for v in row))
    return "\n".join(lines) + "\n"


def data(n: int = 40) -> np.ndarray:
    rng = np.random.default_rng(3)
    return np.column_stack([np.arange(n) * 0.1, 1000 + 50 * rng.standard_normal(n), rng.standard_normal(n)])


@pytest.mark.parametrize("sep, delimiter", [(";", ""), ("\t", 'delimiter = "\\t"'), ("  ", 'delimiter = "whitespace"')])
def test_a_decimal_comma_is_read_to_the_written_digits(tmp_path, sep, delimiter):
    rows = data()
    ds = import_table(write(tmp_path, f'decimal = ","\n{delimiter}', table(rows, sep, ",")))
    for j, name in ((1, "speed"), (2, "T_exh")):
        np.testing.assert_allclose(ds.frame[name].to_numpy(), np.round(rows[:, j], 6), rtol=0, atol=1e-9)
    np.testing.assert_allclose(ds.frame["time"].to_numpy(), rows[:, 0], atol=1e-9)


def test_a_decimal_comma_undeclared_names_the_key_to_set(tmp_path):
    spec = write(tmp_path, 'delimiter = ";"', table(data(), ";", ","))
    with pytest.raises(DataError) as err:
        import_table(spec)
    assert str(err.value) == (f"{tmp_path / 'run.csv'}, column 't', line 2: '0,000000' is not a number "
                              '(a decimal comma? set decimal = "," in the import spec); fix or remove the value')


@pytest.mark.parametrize("head, message", [
    ('decimal = ","\ndelimiter = ","', r'decimal = "," with delimiter = ","; a decimal comma needs another '
                                      r'delimiter: set delimiter = ";"'),
    ('encoding = "klingon"', r'encoding = "klingon" is not a text encoding Python knows; use e.g. "utf-8" '
                             r'\(the default\), "cp1252" or "latin-1"'),
])
def test_a_layout_the_files_cannot_have_is_refused_in_the_spec(tmp_path, head, message):
    with pytest.raises(SpecError, match=message):
        import_table(write(tmp_path, head, table(data(), ";", ",")))


def test_a_bad_cell_in_a_decimal_comma_file_is_reported_at_its_line(tmp_path):
    text = table(data(), ";", ",").splitlines()
    cells = text[5].split(";")
    text[5] = ";".join([cells[0], "12,5x", cells[2]])
    spec = write(tmp_path, 'decimal = ","', "\n".join(text) + "\n")
    with pytest.raises(DataError, match=r"column 'speed', line 6: '12.5x' is not a number; fix or remove the value"):
        import_table(spec)


def test_a_units_row_is_skipped_and_fills_the_units_the_spec_leaves_out(tmp_path):
    rows = data()
    spec = write(tmp_path, "units_row = true", table(rows, ",", ".", units="s,[rpm],degC"))
    ds = import_table(spec)
    assert len(ds.frame) == len(rows)  # the units row is not data
    np.testing.assert_allclose(ds.frame["speed"].to_numpy(), np.round(rows[:, 1], 6), atol=1e-9)
    assert ds.schema["speed"].unit == "rpm" and ds.schema["T_exh"].unit == "degC"


def test_a_units_row_disagreeing_with_the_spec_is_an_error(tmp_path):
    spec = write(tmp_path, "units_row = true", table(data(), ",", ".", units="s,1/min,degC"))
    with pytest.raises(DataError, match=r"column 'speed': unit mismatch: the spec says 'rpm' but the file records "
                                        r"'1/min'"):
        import_table(spec)


def test_lines_after_a_units_row_keep_the_numbers_a_user_sees(tmp_path):
    text = table(data(), ",", ".", units="s,rpm,degC").splitlines()
    text[9] = text[9].replace(text[9].split(",")[2], "oops")
    spec = write(tmp_path, "units_row = true", "\n".join(text) + "\n")
    with pytest.raises(DataError, match=r"column 'T_exh', line 10: 'oops' is not a number"):
        import_table(spec)


def test_an_undeclared_units_row_names_the_key_to_set(tmp_path):
    spec = write(tmp_path, "", table(data(), ",", ".", units="s,rpm,degC"))
    with pytest.raises(DataError) as err:
        import_table(spec)
    assert str(err.value) == (f"{tmp_path / 'run.csv'}, line 2: text where the spec reads numbers ('s', 'rpm', "
                              "'degC') and numbers on line 3: a units row? set units_row = true in the spec (the "
                              "units are then read from it)")


def test_a_units_row_of_the_wrong_width_and_without_a_header_are_refused(tmp_path):
    spec = write(tmp_path, "units_row = true", table(data(), ",", ".", units="s,rpm"))
    with pytest.raises(DataError, match=r"line 2: the units row has 2 fields where the header has 3"):
        import_table(spec)
    spec = write(tmp_path, "units_row = true\nheader = false", table(data(), ",", "."))
    with pytest.raises(SpecError, match=r"units_row = true with header = false"):
        import_table(spec)


def test_european_export_both_at_once(tmp_path):
    rows = data()
    spec = write(tmp_path, 'decimal = ","\nunits_row = true', table(rows, ";", ",", units="s;rpm;°C"))
    ds = import_table(spec)
    np.testing.assert_allclose(ds.frame["T_exh"].to_numpy(), np.round(rows[:, 2], 6), atol=1e-9)
    assert ds.schema["T_exh"].unit == "°C" and list(ds.frame[SEGMENT].unique()) == ["run"]


PREAMBLE = "Test bench 3;;\nOperator: K.;;\nDate: 2026-01-02;;\n"


def test_a_cp1252_export_with_a_preamble_reads_unmodified_and_keeps_file_line_numbers(tmp_path):
    rows = data()
    text = PREAMBLE + table(rows, ";", ",", units="s;1/min;°C")
    (tmp_path / "run.csv").write_bytes(text.encode("cp1252"))
    spec = tmp_path / "spec.toml"
    spec.write_text('name = "bench"\ndt = 0.1\nfiles = ["run.csv"]\ntime = "t"\ndecimal = ","\nunits_row = true\n'
                    'encoding = "cp1252"\nskip_lines = 3\n[columns]\nspeed = { role = "input" }\n'
                    'T_exh = { role = "output" }\n')
    ds = import_table(spec)
    np.testing.assert_allclose(ds.frame["T_exh"].to_numpy(), np.round(rows[:, 2], 6), atol=1e-9)
    assert ds.schema["T_exh"].unit == "°C" and ds.schema["speed"].unit == "1/min" and len(ds.frame) == len(rows)
    bad = text.splitlines()
    bad[12] = bad[12].rsplit(";", 1)[0] + ";hot"  # file line 13: 3 preamble lines, header, units row, 8th data row
    (tmp_path / "run.csv").write_bytes(("\n".join(bad) + "\n").encode("cp1252"))
    with pytest.raises(DataError, match=r"column 'T_exh', line 13: 'hot' is not a number"):
        import_table(spec)
    spec.write_text(spec.read_text().replace('encoding = "cp1252"\n', ""))
    with pytest.raises(DataError) as err:
        import_table(spec)
    assert str(err.value).startswith(f"{tmp_path / 'run.csv'}: not UTF-8 text (invalid start byte at byte ")
    assert str(err.value).endswith('set encoding = "cp1252" (Windows exports; or the file\'s own encoding) in the '
                                   "spec, or save the file as UTF-8")


def test_a_preamble_left_undeclared_or_longer_than_the_file_is_one_line(tmp_path):
    text = PREAMBLE.replace(";;", ",,") + table(data(), ",", ".")
    spec = write(tmp_path, "", text)
    with pytest.raises(DataError) as err:
        import_table(spec)
    assert str(err.value) == (f"{tmp_path / 'run.csv'}, line 4: holds the header ('t', 'speed', 'T_exh'), line 1 "
                              "does not: set skip_lines = 3 in the spec (the lines above the header are not read)")
    spec = write(tmp_path, "skip_lines = 3", text)
    assert len(import_table(spec).frame) == 40
    spec = write(tmp_path, "skip_lines = 300", text)
    with pytest.raises(DataError, match=r"run.csv: has 44 lines, but skip_lines = 300 skips the first 300; set "
                                        r"skip_lines to the number of lines above the header"):
        import_table(spec)


def test_a_headerless_file_below_a_preamble_counts_lines_from_the_file_top(tmp_path):
    rows = data()
    text = "logger v2\n" + "\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n"
    (tmp_path / "run.csv").write_text(text)
    spec = tmp_path / "spec.toml"
    spec.write_text('name = "bench"\ndt = 0.1\nfiles = ["run.csv"]\nheader = false\nskip_lines = 1\n'
                    'names = ["", "speed", "T_exh"]\n' + COLUMNS)
    ds = import_table(spec)
    np.testing.assert_allclose(ds.frame["speed"].to_numpy(), np.round(rows[:, 1], 6), atol=1e-9)
    lines = text.splitlines()
    lines[4] = lines[4] + ",9"  # file line 5: one field too many
    (tmp_path / "run.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"run.csv, line 5: 4 fields where the first line has 3"):
        import_table(spec)


def test_a_preamble_above_a_header_of_another_delimiter_names_both_keys(tmp_path):
    spec = write(tmp_path, "", PREAMBLE + table(data(), ";", "."))
    with pytest.raises(DataError, match=r"run.csv, line 4: holds the header \('t', 'speed', 'T_exh'\), line 1 does "
                                        r'not: set skip_lines = 3 and delimiter = ";" in the spec'):
        import_table(spec)
