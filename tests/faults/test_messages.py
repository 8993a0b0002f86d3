"""Each fault's line names its real cause and is the same from run to run: a damaged
``meta.json``, an empty colour frame, an undecodable JPEG, an unknown ground-truth format (a
usage error like every other bad choice), a full disk while the query sidecar is written."""

from __future__ import annotations

import errno
import io
from pathlib import Path

import numpy as np
import pytest

from tests.support.faults import assert_fault, snapshot
from tests.support.recordings import grey_bag

pytestmark = pytest.mark.slow


def _empty_raw(T, t, header):
    return T["sensor_msgs/msg/Image"](
        header=header, height=0, width=0, encoding="rgb8", is_bigendian=0, step=0,
        data=np.zeros(0, np.uint8),
    )  # fmt: skip


def _jpeg(data: bytes):
    def make(T, t, header):
        return T["sensor_msgs/msg/CompressedImage"](
            header=header, format="rgb8; jpeg compressed bgr8", data=np.frombuffer(data, np.uint8)
        )

    return make


def _good_jpeg() -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.full((24, 32, 3), 90, np.uint8)).save(out, format="JPEG")
    return out.getvalue()


def test_empty_colour_frame_is_said_to_be_empty(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "bag", colour=_empty_raw)
    code, _, err = care("ingest", bag, "--out", tmp_path / "store")
    line = assert_fault(code, err, r"/camera/color/image_raw: a colour image is 0x0, empty")
    assert "depth images" not in line  # not a size mismatch with the depth stream
    assert not (tmp_path / "store").exists()


@pytest.mark.parametrize(
    "data",
    [b"this is not an image at all" * 4, _good_jpeg()[:60]],
    ids=["garbage", "truncated-jpeg"],
)
def test_undecodable_jpeg_gives_the_same_line_every_run(care, tmp_path: Path, data: bytes) -> None:
    bag = grey_bag(tmp_path / "bag", colour=_jpeg(data))
    lines = []
    for run in range(2):
        code, _, err = care("ingest", bag, "--out", tmp_path / f"store{run}")
        lines.append(
            assert_fault(code, err, r"/camera/color/image_raw: cannot decode", clean=(tmp_path,))
        )
    assert " at 0x" not in lines[0]
    assert lines[0].replace("store0", "") == lines[1].replace("store1", "")
    good = grey_bag(tmp_path / "good", colour=_jpeg(_good_jpeg()))
    assert care("ingest", good, "--out", tmp_path / "store")[0] == 0


def test_meta_json_emptied_is_damaged(care, copy_good) -> None:
    store = copy_good("store")
    (store / "meta.json").write_text("{}")
    for args in (("check", store), ("fuse", "grid", store), ("query", store, "chair")):
        code, _, err = care(*args)
        line = assert_fault(code, err, r"meta\.json: damaged")
        assert "schema version None" not in line
        assert "care ingest" in line  # the command that rebuilds it


def test_unknown_gt_format_is_a_usage_error(care, good: Path, tmp_path: Path) -> None:
    code, _, err = care("eval", good / "store", "--out", tmp_path / "ev", "--gt-format", "obj")
    assert_fault(code, err, r"'--gt-format'.*'obj' is not one of", exit_code=2)
    code, _, err = care("run", "--out", tmp_path / "ev", "--gt-format", "obj")
    assert_fault(code, err, r"'--gt-format'.*'obj' is not one of", exit_code=2)
    assert not (tmp_path / "ev").exists()


class _FullDisk(io.RawIOBase):
    """A file on a disk that fills after ``room`` bytes: later writes fail with ENOSPC, as
    the kernel says it (a flush at close included)."""

    def __init__(self, room: int) -> None:
        self.room = room
        self.pos = 0

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        self.pos = offset if whence == 0 else self.pos + offset
        return self.pos

    def tell(self) -> int:
        return self.pos

    def write(self, b) -> int:
        n = len(b)
        if n > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.room -= n
        self.pos += n
        return n


def test_full_disk_in_the_query_sidecar_leaves_no_temporary(
    care, copy_good, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The sidecar's buffered files fail again when closed after the failed write; the
    staged folder goes all the same, and the line's "nothing half-written" is true."""
    import care_maps.fuse.sidecar

    real = care_maps.fuse.sidecar._npy

    def npy(path: Path, dtype: str, shape: tuple[int, ...]):
        out = io.BufferedWriter(_FullDisk(room=0))  # the header waits in the buffer
        real_header = real(path, dtype, shape)  # the real file exists on disk, as it would
        real_header.close()
        np.lib.format.write_array_header_2_0(out, {"descr": np.dtype(dtype).str,
                                                   "fortran_order": False, "shape": shape})  # fmt: skip
        return out

    monkeypatch.setattr(care_maps.fuse.sidecar, "_npy", npy)
    store = copy_good("store")
    before = snapshot(store)
    code, _, err = care("fuse", "grid", store, "--overwrite")
    assert_fault(code, err, r"no space left on device", clean=(store.parent,), intact=before)
    monkeypatch.setattr(care_maps.fuse.sidecar, "_npy", real)
    assert care("fuse", "grid", store, "--overwrite")[0] == 0
