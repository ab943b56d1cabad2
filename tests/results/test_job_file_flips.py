"""Every damaged byte of a job file is noticed: each byte flipped (two ways, over a bounded sample of positions
covering the whole file) is either detected on reading (one of READ_ERRORS: the job counts as damaged and
``run --resume`` computes it again) or harmless (the rows and metadata read back equal the original's)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from enginebench.results.atomic import READ_ERRORS
from enginebench.results.job_files import encode_job, load_job

POSITIONS = 800
"""Byte positions tried (evenly over the file, the footer's every byte included), two flips each."""


def _job() -> tuple[pd.DataFrame, dict]:
    rows = pd.DataFrame([{"dataset": "d", "target": "y", "mode": "static", "window": 0.0, "method": "krls",
                          "family": "data-driven", "repetition": r, "split": "test", "metric": m,
                          "value": 0.3876 + 0.01 * r + i, "status": "ok"}
                         for r in range(2) for i, m in enumerate(("mae", "rmse", "nrmse"))])
    return rows, {"status": "ok", "method": "krls", "params": {"gamma": 0.1, "lambda": 1e-3}, "timings": {"fit_s": 0.5}}


def test_every_flipped_byte_is_detected_or_harmless(tmp_path):
    rows, meta = _job()
    data, _ = encode_job(rows, meta)
    path = tmp_path / "job.parquet"
    path.write_bytes(data)
    good_rows, good_meta = load_job(path)
    n = len(data)
    footer = int.from_bytes(data[-8:-4], "little") + 8  # the Parquet footer: metadata, column names, schema
    positions = np.unique(np.r_[np.linspace(0, n - footer - 1, POSITIONS).astype(int), np.arange(n - footer, n)])
    silent = []
    for pos in positions:
        for mask in (0x01, 0x80):
            flipped = bytearray(data)
            flipped[pos] ^= mask
            path.write_bytes(bytes(flipped))
            try:
                got_rows, got_meta = load_job(path)
            except READ_ERRORS:
                continue
            if not (got_meta == good_meta and got_rows.equals(good_rows)):
                silent.append((int(pos), mask))
    assert not silent, f"{len(silent)} flips read back changed without detection, first {silent[:5]} of {n} bytes"
