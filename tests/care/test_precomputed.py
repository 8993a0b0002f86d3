"""Precomputed features written by pyarrow (as another tool would), read back by stamp."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from care.encoders import EncoderOptions, make_encoder
from care.encoders.precomputed import text_path_for
from care.errors import EncoderError
from care.frames import Frame

STAMPS = [1_000_000_000 + i * 100_000_000 for i in range(6)]


def _maps() -> np.ndarray:
    return np.random.default_rng(0).normal(size=(len(STAMPS), 3, 4, 5)).astype(np.float32)


@pytest.fixture
def feature_file(tmp_path: Path) -> Path:
    path = tmp_path / "lseg.parquet"
    maps = _maps()
    table = pa.table(
        {
            "stamp_ns": pa.array(STAMPS[::-1], pa.int64()),  # any order
            "fh": pa.array([3] * len(STAMPS), pa.int16()),
            "fw": pa.array([4] * len(STAMPS), pa.int16()),
            "feature": pa.array(
                [m.ravel().astype(np.float16) for m in maps[::-1]], pa.list_(pa.float16())
            ),
        }
    )
    pq.write_table(table, path, row_group_size=2)
    text = pa.table(
        {"name": ["chair", "table"], "embedding": [[1.0, 0, 0, 0, 0], [0, 3.0, 0, 0, 0]]}
    )
    pq.write_table(text, text_path_for(path))
    return path


def _frame(stamp: int) -> Frame:
    return Frame(
        stamp, np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32), np.eye(3), np.eye(4)
    )


def test_views_found_by_stamp_and_normalised(feature_file: Path) -> None:
    enc = make_encoder("precomputed", EncoderOptions(precomputed=feature_file))
    assert enc.dim == 5
    got = enc.encode_views([_frame(STAMPS[4] + 400_000), _frame(STAMPS[1])])  # within 1 ms
    ref = _maps()[[4, 1]].astype(np.float16).astype(np.float32)
    ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
    np.testing.assert_allclose(got, ref, atol=1e-6)


def test_text_side(feature_file: Path) -> None:
    enc = make_encoder("precomputed", EncoderOptions(precomputed=feature_file))
    np.testing.assert_allclose(
        enc.encode_text(["table", "chair"]), [[0, 1, 0, 0, 0], [1, 0, 0, 0, 0]]
    )
    with pytest.raises(EncoderError, match="no embedding for \\['sofa'\\]"):
        enc.encode_text(["sofa"])


def test_missing_stamp_and_file_are_clear(feature_file: Path, tmp_path: Path) -> None:
    enc = make_encoder("precomputed", EncoderOptions(precomputed=feature_file))
    with pytest.raises(EncoderError, match="no features for the view stamped 1050000000 ns"):
        enc.encode_views([_frame(1_050_000_000)])
    with pytest.raises(EncoderError, match="--precomputed"):
        make_encoder("precomputed", EncoderOptions())
    with pytest.raises(EncoderError, match="cannot read precomputed features"):
        make_encoder("precomputed", EncoderOptions(precomputed=tmp_path / "absent.parquet"))
