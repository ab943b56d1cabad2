"""Parquet I/O: round trip, column projection, corruption detection, atomic writes."""

from __future__ import annotations

import json
import struct
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from enginebench.datasets import io as dio
from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import read_dataset, read_metadata, write_dataset
from enginebench.datasets.schema import Schema
from enginebench.errors import DataError

MARK = 12345.678901  # a value whose 8 bytes are easy to find in an uncompressed file


def make_dataset(rng: np.random.Generator, lengths=(50, 30, 20)) -> Dataset:
    seg = np.repeat([f"voyage-{i}" for i in range(len(lengths))], lengths)
    time = np.concatenate([np.arange(n) * 3.0 for n in lengths])
    n = len(seg)
    frame = pd.DataFrame(
        {
            SEGMENT: seg,
            TIME: time,
            "speed": rng.uniform(400, 1030, n),
            "T_exh": rng.normal(350, 20, n),
            "p_lube": rng.normal(4.0, 0.1, n),
            "engine": np.where(np.arange(n) % 2 == 0, "port", "starboard"),
        }
    )
    frame.loc[n // 2, "T_exh"] = MARK
    schema = Schema.from_roles(
        {"speed": "input", "T_exh": "output", "p_lube": "internal", "engine": "group"},
        {"speed": "rpm", "T_exh": "degC", "p_lube": "bar"},
    )
    split = {"train": ["voyage-0"], "test": ["voyage-2"]}
    meta = {"provenance": "synthetic test", "licence": "CC0-1.0", "split": split}
    return Dataset(name="test-ds", frame=frame, schema=schema, dt=3.0, meta=meta)


@pytest.fixture
def ds() -> Dataset:
    return make_dataset(np.random.default_rng(0))


def test_round_trip_restores_values_schema_dt_meta(ds, tmp_path):
    path = write_dataset(ds, tmp_path / "d.parquet")
    back = read_dataset(path)
    pd.testing.assert_frame_equal(back.frame, ds.frame[[SEGMENT, TIME, *ds.schema.names()]])
    assert back.schema == ds.schema
    assert back.dt == ds.dt and back.name == ds.name
    assert back.meta == ds.meta
    assert back.content_hash() == ds.content_hash()
    assert back.segment_ids == ["voyage-0", "voyage-1", "voyage-2"]


def test_content_hash_is_stored_stable_and_sensitive(ds, tmp_path):
    a = write_dataset(ds, tmp_path / "a.parquet")
    b = write_dataset(make_dataset(np.random.default_rng(0)), tmp_path / "b.parquet")
    assert read_metadata(a)["content_hash"] == read_metadata(b)["content_hash"] == ds.content_hash()
    changed = ds.frame.copy()
    changed.loc[3, "speed"] += 1e-9
    assert ds.with_frame(changed).content_hash() != ds.content_hash()


def test_read_metadata_reads_the_footer_only(ds, tmp_path, monkeypatch):
    path = write_dataset(ds, tmp_path / "d.parquet")

    def no_data(*args, **kwargs):
        raise AssertionError("read_metadata must not read data pages")

    monkeypatch.setattr(dio.pq, "read_table", no_data)
    meta = read_metadata(path)
    assert meta["name"] == "test-ds" and meta["dt"] == 3.0
    assert meta["rows"] == 100 and meta["segments"] == 3
    assert meta["schema"]["T_exh"] == {"role": "output", "unit": "degC"}
    assert meta["meta"]["licence"] == "CC0-1.0"


def test_projection_reads_only_requested_columns(ds, tmp_path, monkeypatch):
    path = write_dataset(ds, tmp_path / "d.parquet")
    asked: list[list[str]] = []
    real = pq.read_table

    def spy(*args, **kwargs):
        asked.append(list(kwargs["columns"]))
        return real(*args, **kwargs)

    monkeypatch.setattr(dio.pq, "read_table", spy)
    part = read_dataset(path, columns=["T_exh", "engine"])
    assert asked == [[SEGMENT, TIME, "T_exh", "engine"]]
    assert list(part.frame.columns) == [SEGMENT, TIME, "T_exh", "engine"]
    assert part.schema.names() == ["T_exh", "engine"] and part.schema["T_exh"].unit == "degC"
    np.testing.assert_array_equal(part.frame["T_exh"].to_numpy(), ds.frame["T_exh"].to_numpy())


def test_projection_of_unknown_column_is_named(ds, tmp_path):
    path = write_dataset(ds, tmp_path / "d.parquet")
    with pytest.raises(DataError) as e:
        read_dataset(path, columns=["T_exh", "NOx"])
    assert str(e.value) == f"file {path} has no column(s) 'NOx'; the dataset has 'speed', 'T_exh', 'p_lube', 'engine'"


def test_flipped_bytes_are_detected(ds, tmp_path):
    path = write_dataset(ds, tmp_path / "d.parquet", compression="none")
    raw = bytearray(path.read_bytes())
    at = raw.find(struct.pack("<d", MARK))
    assert at > 0
    raw[at + 3] ^= 0xFF
    bad = tmp_path / "copy.parquet"
    bad.write_bytes(bytes(raw))
    for columns in (None, ["T_exh"]):
        with pytest.raises(DataError) as e:
            read_dataset(bad, columns=columns)
        assert str(e.value).startswith(f"file {bad} is corrupted: ")
        assert "\n" not in str(e.value)
    # pages are checked one by one: the undamaged columns stay readable
    ok = read_dataset(bad, columns=["speed"])
    np.testing.assert_array_equal(ok.frame["speed"].to_numpy(), ds.frame["speed"].to_numpy())


def test_values_rewritten_by_another_tool_fail_the_content_hash(ds, tmp_path):
    path = write_dataset(ds, tmp_path / "d.parquet")
    table = pq.read_table(path)
    speed = table.column("speed").to_numpy().copy()
    speed[7] += 1.0
    edited = table.set_column(table.schema.get_field_index("speed"), "speed", pa.array(speed))
    pq.write_table(edited.replace_schema_metadata(table.schema.metadata), path)
    changed = ds.frame.copy()
    changed.loc[7, "speed"] += 1.0
    with pytest.raises(DataError) as e:
        read_dataset(path)
    assert str(e.value) == (
        f"file {path} is corrupted: content hash mismatch (stored {ds.content_hash()[:12]}, computed "
        f"{ds.with_frame(changed).content_hash()[:12]}); its values changed after it was written - "
        "restore it from a backup or re-create it from its source"
    )


def test_not_parquet_and_plain_parquet_are_rejected(tmp_path):
    text = tmp_path / "notes.parquet"
    text.write_text("t,speed\n0,1\n")
    with pytest.raises(DataError) as e:
        read_dataset(text)
    assert str(e.value).startswith(f"file {text} is not a Parquet file (")
    plain = tmp_path / "plain.parquet"
    pq.write_table(pa.table({"t": [0.0, 1.0]}), plain)
    for reader in (read_dataset, read_metadata):
        with pytest.raises(DataError) as e:
            reader(plain)
        assert str(e.value) == (
            f"file {plain} is a Parquet file without enginebench metadata (roles, units, dt); "
            "import it through a TOML import spec that declares them"
        )
    with pytest.raises(DataError, match="not found"):
        read_dataset(tmp_path / "absent.parquet")


def test_write_is_atomic(ds, tmp_path, monkeypatch):
    path = write_dataset(ds, tmp_path / "d.parquet")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.parquet"]
    before = path.read_bytes()
    real = pq.write_table

    def crash(table, where, **kwargs):
        real(table.slice(0, 10), where, **kwargs)  # a partial file under the temporary name
        raise KeyboardInterrupt("power cut")

    monkeypatch.setattr(dio.pq, "write_table", crash)
    other = make_dataset(np.random.default_rng(1))
    with pytest.raises(KeyboardInterrupt):
        write_dataset(other, path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.parquet"]
    assert path.read_bytes() == before
    assert read_dataset(path).content_hash() == ds.content_hash()


def test_meta_keeps_json_values_and_drops_the_rest(ds, tmp_path):
    odd = Dataset(ds.name, ds.frame, ds.schema, ds.dt, {**ds.meta, "n": np.int64(5), "w": np.arange(3), "f": object()})
    with pytest.warns(UserWarning, match="'f' are not JSON-serialisable"):
        path = write_dataset(odd, tmp_path / "d.parquet")
    meta = read_dataset(path).meta
    assert meta["n"] == 5 and meta["w"] == [0, 1, 2] and "f" not in meta
    assert json.dumps(meta)


@settings(max_examples=25, deadline=None)
@given(
    lengths=st.lists(st.integers(1, 12), min_size=1, max_size=4),
    seed=st.integers(0, 2**32 - 1),
    dt=st.floats(1e-3, 1e3, allow_nan=False),
)
def test_round_trip_property(lengths, seed, dt):
    rng = np.random.default_rng(seed)
    n = sum(lengths)
    frame = pd.DataFrame(
        {
            SEGMENT: np.repeat([f"s{i}" for i in range(len(lengths))], lengths),
            TIME: np.concatenate([np.arange(k) * dt for k in lengths]),
            "x": rng.normal(0, 10.0 ** rng.integers(-300, 300), n),
            "y": rng.integers(-5, 5, n).astype(float),
            "g": rng.choice(["a", "b", "ü"], n),
        }
    )
    ds = Dataset("p", frame, Schema.from_roles({"x": "input", "y": "output", "g": "group"}), dt, {"k": [1, "2"]})
    with tempfile.TemporaryDirectory() as d:
        back = read_dataset(write_dataset(ds, Path(d) / "p.parquet"))
    pd.testing.assert_frame_equal(back.frame, ds.frame)
    assert back.content_hash() == ds.content_hash() and back.dt == dt and back.meta == ds.meta
