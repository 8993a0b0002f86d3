"""``as_numpy`` reads Arrow columns from their buffers; pyarrow's own ``to_numpy`` is the
reference, on sliced, chunked, boolean, empty and null-holding columns."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pyarrow as pa
import pytest

from care_maps.core.store import as_numpy

TYPES = [
    pa.int8(),
    pa.int16(),
    pa.int32(),
    pa.int64(),
    pa.uint8(),
    pa.float16(),
    pa.float32(),
    pa.float64(),
]


@pytest.mark.parametrize("kind", TYPES, ids=str)
def test_numbers_equal_pyarrow_also_sliced(kind: pa.DataType) -> None:
    values = (
        np.arange(-5, 20).astype(kind.to_pandas_dtype())
        if not pa.types.is_unsigned_integer(kind)
        else np.arange(25).astype(np.uint8)
    )
    array = pa.array(values, type=kind)
    for part in (array, array.slice(3, 11), array.slice(0, 0)):
        got = as_numpy(part)
        want = part.to_numpy(zero_copy_only=False)
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


def test_booleans_at_every_offset() -> None:
    rng = np.random.default_rng(3)
    array = pa.array(rng.random(37) < 0.5)
    for start in range(9):
        part = array.slice(start, 20)
        np.testing.assert_array_equal(as_numpy(part), part.to_numpy(zero_copy_only=False))


def test_chunked_lists_and_nulls() -> None:
    chunked = pa.chunked_array([pa.array([1.5, 2.5], pa.float32()), pa.array([3.5], pa.float32())])
    np.testing.assert_array_equal(as_numpy(chunked), [1.5, 2.5, 3.5])
    lists = pa.array([[1, 2], [3, 4], [5, 6]], pa.list_(pa.int16())).slice(1)
    np.testing.assert_array_equal(as_numpy(lists.flatten()), [3, 4, 5, 6])
    with_nulls = pa.array([1.0, None, 3.0])
    np.testing.assert_array_equal(as_numpy(with_nulls), with_nulls.to_numpy(zero_copy_only=False))


def test_reading_numbers_does_not_import_pandas(tmp_path) -> None:
    code = (
        "import sys, pyarrow.parquet as pq\n"
        "from care_maps.core.store import as_numpy\n"
        f"t = pq.ParquetFile({str(tmp_path / 't.parquet')!r}).read()\n"
        "as_numpy(t.column('x')); as_numpy(t.column('b'))\n"
        "print('pandas' in sys.modules)\n"
    )
    import pyarrow.parquet as pq

    pq.write_table(
        pa.table({"x": pa.array([1.0, 2.0]), "b": pa.array([True, False])}), tmp_path / "t.parquet"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
