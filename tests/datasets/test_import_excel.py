"""Excel workbooks read as an import spec's files: one sheet, typed cells, rows numbered as Excel shows them,
empty rows under the header and at the bottom left out, the others reported."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.importer import import_table
from enginebench.errors import DataError

pytest.importorskip("openpyxl")

COLUMNS = '[columns]\nspeed = { role = "input" }\nT_exh = { role = "output" }\n'


def workbook(tmp_path: Path, rows: list[list], sheets: dict[str, list[list]] | None = None) -> Path:
    path = tmp_path / "bench.xlsx"
    with pd.ExcelWriter(path, engine="openpyxl") as xl:
        for name, body in {"data": rows, **(sheets or {})}.items():
            pd.DataFrame(body).to_excel(xl, sheet_name=name, header=False, index=False)
    return path


def spec(tmp_path: Path, head: str = "") -> Path:
    path = tmp_path / "spec.toml"
    path.write_text(f'name = "bench"\ndt = 0.5\nfiles = ["bench.xlsx"]\n{head}\n{COLUMNS}')
    return path


def test_a_sheet_is_read_to_the_stored_values_and_its_empty_edge_rows_left_out(tmp_path):
    rng = np.random.default_rng(0)
    data = rng.normal(size=(20, 2))
    rows = [[None, "speed", "T_exh"], [None, None, None]] + [[i, *r] for i, r in enumerate(data)] + [[None] * 3]
    workbook(tmp_path, rows)
    ds = import_table(spec(tmp_path))
    assert len(ds.frame) == 20 and ds.segment_ids == ["bench"]
    np.testing.assert_allclose(ds.frame["speed"].to_numpy(), data[:, 0], rtol=1e-15)  # stored to 17 digits
    np.testing.assert_allclose(ds.frame["T_exh"].to_numpy(), data[:, 1], rtol=1e-15)


def test_a_bad_cell_is_named_by_its_excel_row(tmp_path):
    rows = [["speed", "T_exh"], [None, None]] + [[float(i), 2.0 * i] for i in range(10)]
    rows[6][1] = "n.a."  # Excel row 7: header, one empty row, then data from row 3
    workbook(tmp_path, rows)
    with pytest.raises(DataError, match=r"bench.xlsx, column 'T_exh', row 7: 'n.a.' is not a number"):
        import_table(spec(tmp_path))


def test_an_empty_row_between_data_rows_is_reported_not_dropped(tmp_path):
    rows = [["speed", "T_exh"]] + [[float(i), 2.0 * i] for i in range(10)]
    rows[5] = [None, None]  # Excel row 6: dropping it would shift the sample index after it
    workbook(tmp_path, rows)
    with pytest.raises(DataError, match=r"column 'speed', row 6: missing value; fill it or remove the row"):
        import_table(spec(tmp_path))


def test_the_named_sheet_its_units_row_and_a_missing_sheet(tmp_path):
    other = [["speed", "T_exh"], ["[rpm]", "degC"]] + [[1000.0 + i, 600.0 - i] for i in range(5)]
    workbook(tmp_path, [["x"], [1.0]], sheets={"bench 2": other})
    ds = import_table(spec(tmp_path, 'sheet = "bench 2"\nunits_row = true'))
    np.testing.assert_array_equal(ds.frame["speed"].to_numpy(), 1000.0 + np.arange(5))
    assert ds.schema["speed"].unit == "rpm" and ds.schema["T_exh"].unit == "degC"
    with pytest.raises(DataError) as err:
        import_table(spec(tmp_path, 'sheet = "Bench 2"'))
    assert str(err.value) == (f"{tmp_path / 'bench.xlsx'}: no sheet 'Bench 2'; the workbook's sheets are 'data', "
                              "'bench 2': set sheet = \"NAME\" in the spec")


def test_an_old_xls_workbook_is_refused_with_what_to_do(tmp_path):
    (tmp_path / "bench.xls").write_bytes(b"\xd0\xcf\x11\xe0")
    path = tmp_path / "spec.toml"
    path.write_text(f'name = "bench"\ndt = 0.5\nfiles = ["bench.xls"]\n{COLUMNS}')
    with pytest.raises(DataError, match=r"unsupported file type '.xls'; give CSV .*, Parquet .* or Excel "
                                        r"\(.xlsx, .xlsm\) files; save an .xls workbook as .xlsx"):
        import_table(path)
