"""Reading one sheet of an Excel workbook (.xlsx, .xlsm) as an import spec's data file.

Test benches and steady-state campaigns are often delivered as workbooks. A sheet is read
as a CSV file would be (``header``, ``names``, ``skip_lines``, ``units_row``), its cells
typed as Excel stores them; messages count rows as Excel shows them (row 1 at the top).
Rows empty in every cell directly under the header or after the last data row are dropped
(workbooks often hold them); an empty row between data rows stays and is reported where a
value is missing, since dropping it would shift the sample index of a record without a time
column. Needs openpyxl (``pip install 'enginebench[excel]'``), read through pandas.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from enginebench.datasets.import_spec import ImportSpec, one_line
from enginebench.errors import DataError



def read_sheet(file: Path, spec: ImportSpec) -> tuple[pd.DataFrame, np.ndarray]:
    """The spec's sheet of ``file`` below ``skip_lines``: cells (columns 0..n-1, untyped objects) and each row's
    Excel row number; rows empty in every cell at the top and the bottom left out."""
    if importlib.util.find_spec("openpyxl") is None:  # pandas reads .xlsx through it
        raise DataError(f"{file}: reading an Excel workbook needs openpyxl: pip install 'enginebench[excel]' "
                        "(or save the sheet as CSV)")
    sheet: Any = spec.sheet if spec.sheet is not None else 0
    try:
        book = pd.ExcelFile(file, engine="openpyxl")
    except Exception as exc:  # a damaged or mis-named workbook: openpyxl's own error, on one line
        raise DataError(f"{file}: not a readable Excel workbook ({one_line(str(exc))}); save it again as .xlsx, or "
                        "as CSV") from exc
    with book:
        if spec.sheet is not None and spec.sheet not in book.sheet_names:
            raise DataError(f"{file}: no sheet {spec.sheet!r}; the workbook's sheets are "
                            f"{', '.join(repr(s) for s in book.sheet_names)}: set sheet = \"NAME\" in the spec")
        cells = pd.read_excel(book, sheet_name=sheet, header=None, dtype=object)
    rows = np.arange(1, len(cells) + 1)
    cells, rows = cells.iloc[spec.skip_lines:], rows[spec.skip_lines:]
    filled = cells.notna().any(axis=1).to_numpy()
    if not filled.any():
        raise DataError(f"{file}: sheet {sheet!r} holds no cells" + (f" after skip_lines = {spec.skip_lines}"
                                                                    if spec.skip_lines else ""))
    first = int(np.argmax(filled))  # empty rows above the header (or the first data row) hold nothing: left out
    cells, rows, filled = cells.iloc[first:], rows[first:], filled[first:]
    keep = _trim(filled, 1 if spec.header else 0, 1 if spec.units_row else 0)
    cells = cells.iloc[keep].reset_index(drop=True)
    cells.columns = range(cells.shape[1])
    return cells, rows[keep]


def _trim(filled: np.ndarray, header: int, units: int) -> np.ndarray:
    """Positions kept: the header (and units) rows, then the data rows less the empty ones above the first
    filled data row and below the last."""
    top = header + units
    data = np.flatnonzero(filled[top:]) + top
    if not data.size:
        return np.arange(top)
    return np.concatenate([np.arange(top), np.arange(data[0], data[-1] + 1)])


def cell_text(v: Any) -> str:
    """A header or units cell as text: '' for an empty one, whole numbers without '.0'."""
    if v is None or (isinstance(v, float) and np.isnan(v)):
        return ""
    if isinstance(v, float) and v.is_integer():
        return str(int(v))
    return str(v).strip()
