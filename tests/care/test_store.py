"""The feature store: round trip, atomic commit, and readability by other tools."""

from __future__ import annotations

import json
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from care_maps.core.errors import StoreError
from care_maps.core.frames import Frame
from care_maps.core.store import (
    EncoderInfo,
    Store,
    StoreWriter,
    group_rows,
    iter_batches,
    read_table,
    write_table_atomic,
)


def _smooth_rgb(i: int) -> np.ndarray:
    u, v = np.meshgrid(np.arange(32) * 8, np.arange(24) * 10)
    return np.stack([u, v, np.full_like(u, 9 * i)], axis=-1).clip(0, 255).astype(np.uint8)


def _frame(i: int) -> Frame:
    rng = np.random.default_rng(i)
    pose = np.eye(4)
    pose[:3, 3] = [i, 0.5, 1.5]
    return Frame(
        stamp_ns=1_000_000_000 + i * 33_000_000,
        rgb=_smooth_rgb(i),
        depth_m=np.round(rng.uniform(0.5, 4.0, (24, 32)), 3).astype(np.float32),
        K=np.array([[30.0, 0, 16], [0, 30, 12], [0, 0, 1]]),
        cam_to_world=pose,
        extras={"instance": rng.integers(0, 9, (24, 32), dtype=np.uint16)},
    )


def _features(i: int) -> np.ndarray:
    f = np.random.default_rng(100 + i).normal(size=(3, 4, 8)).astype(np.float32)
    return f / np.linalg.norm(f, axis=-1, keepdims=True)


def _write(path: Path, n: int = 5) -> None:
    info = EncoderInfo("test", "1", 8, ("chair", "table"))
    with StoreWriter(path, info, rows_per_group=2) as writer:
        for i in range(n):
            writer.add(_frame(i), _features(i))
        writer.set_text(["chair", "table"], np.eye(2, 8, dtype=np.float32))
        writer.commit({"source": "synthetic"})


def test_round_trip(tmp_path: Path) -> None:
    _write(tmp_path / "s")
    store = Store(tmp_path / "s")
    assert store.num_views == 5
    assert store.encoder == EncoderInfo("test", "1", 8, ("chair", "table"))
    for (vid, frame), i in zip(store.iter_frames(), range(5), strict=True):
        ref = _frame(i)
        assert vid == i
        assert frame.stamp_ns == ref.stamp_ns
        np.testing.assert_array_equal(frame.K, ref.K)
        np.testing.assert_array_equal(frame.cam_to_world, ref.cam_to_world)
        np.testing.assert_allclose(frame.depth_m, ref.depth_m, atol=5e-4)  # millimetre PNG
        np.testing.assert_array_equal(frame.extras["instance"], ref.extras["instance"])
        assert np.abs(frame.rgb.astype(int) - ref.rgb).max() <= 8  # JPEG q95, 4:4:4
    for vid, feat in store.iter_features():
        np.testing.assert_allclose(feat, _features(vid), atol=1e-3)
    names, emb = store.text_embeddings()
    assert names == ["chair", "table"]
    assert emb.shape == (2, 8)
    assert store.poses().shape == (5, 4, 4)


def test_no_columns_reads_no_columns(tmp_path: Path) -> None:
    """``read_table(path, [])`` is the rows' count and the metadata, not every column: a
    goal query read a grid's layout so, and decoded the map's features with it."""
    _write(tmp_path / "s")
    path = tmp_path / "s" / "features.parquet"
    header = read_table(path, [])
    assert (header.num_columns, header.num_rows) == (0, 5)
    assert header.schema.metadata == pq.read_schema(path).metadata
    assert read_table(path, None).num_columns == len(pq.read_schema(path).names)
    assert [b.num_columns for b in iter_batches(path, 2, [])] == [0, 0, 0]


def test_readable_by_polars_and_duckdb(tmp_path: Path) -> None:
    _write(tmp_path / "s")
    views = pl.read_parquet(tmp_path / "s" / "views.parquet")
    assert views.height == 5
    assert views["K"].to_list()[0][0] == 30.0
    # the feature column is the map's float16 bytes: 2 a value
    n, length = duckdb.sql(
        f"select count(*), max(octet_length(feature)) from '{tmp_path / 's' / 'features.parquet'}'"
    ).fetchall()[0]
    assert (n, length) == (5, 2 * 3 * 4 * 8)


def test_interrupted_write_leaves_no_store(tmp_path: Path) -> None:
    path = tmp_path / "s"

    def interrupted() -> None:
        with StoreWriter(path, None) as writer:
            writer.add(_frame(0))
            raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError):
        interrupted()
    assert not path.exists()
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(StoreError, match="not a complete feature store"):
        Store(path)


def test_rewrite_replaces_previous_store_atomically(tmp_path: Path) -> None:
    _write(tmp_path / "s", n=3)
    _write(tmp_path / "s", n=2)
    assert Store(tmp_path / "s").num_views == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


def test_other_schema_version_is_refused(tmp_path: Path) -> None:
    _write(tmp_path / "s")
    meta = json.loads((tmp_path / "s" / "meta.json").read_text())
    meta["schema_version"] = 99
    (tmp_path / "s" / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(StoreError, match="schema version 99"):
        Store(tmp_path / "s")


def test_row_groups_are_cut_by_list_values(tmp_path: Path) -> None:
    """A feature-like list column of 1,000,000 values a row: 4 rows a group (2^22 / 1e6)."""
    values = np.zeros((10, 1_000_000), np.float16)
    offsets = pa.array(np.arange(11, dtype=np.int32) * 1_000_000)
    table = pa.table(
        {
            "id": pa.array(np.arange(10, dtype=np.int32)),
            "feature": pa.ListArray.from_arrays(offsets, pa.array(values.ravel(), pa.float16())),
        }
    )
    assert group_rows(table) == 4
    assert group_rows(table.drop_columns(["feature"])) == 1 << 22
    write_table_atomic(table, tmp_path / "t.parquet")
    meta = pq.ParquetFile(tmp_path / "t.parquet").metadata
    assert [meta.row_group(i).num_rows for i in range(meta.num_row_groups)] == [4, 4, 2]
    assert read_table(tmp_path / "t.parquet").equals(
        table.replace_schema_metadata(read_table(tmp_path / "t.parquet").schema.metadata)
    )


@pytest.mark.parametrize("column", ["depth_zstd", "rgb_jpeg"])
def test_a_flipped_byte_inside_an_image_is_a_damaged_table(tmp_path: Path, column: str) -> None:
    """An image's bytes are kept uncompressed by Parquet, and a zstd frame has no checksum of
    its own: damage inside one must be found by the pages' CRC, not decoded into wrong data."""
    _write(tmp_path / "s")
    path = tmp_path / "s" / "views.parquet"
    blob = pq.read_table(path, columns=[column]).column(0)[2].as_py()
    data = bytearray(path.read_bytes())
    at = data.find(blob) + len(blob) // 2
    data[at : at + 8] = bytes(b ^ 0xFF for b in data[at : at + 8])
    path.write_bytes(bytes(data))
    store = Store(tmp_path / "s")  # opens: the size is unchanged
    with pytest.raises(StoreError, match=r"views\.parquet: damaged or truncated table"):
        list(store.iter_frames())
