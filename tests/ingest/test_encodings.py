"""Every supported image encoding, end to end: a hand-built bag in, the expected arrays out."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from care_maps.core.errors import IngestError
from care_maps.ingest.source import RecordingFrames
from tests.support.frames import smooth_rgb
from tests.support.messages import compressed_msg, image_msg, jpeg_bytes, png_bytes
from tests.support.recordings import rgbd_messages, write_bag

H, W = 24, 32


def _depth_m(i: int) -> np.ndarray:
    v = np.arange(H, dtype=np.float32)[:, None]
    d = np.broadcast_to(0.8 + 0.05 * v + 0.1 * i, (H, W)).astype(np.float32).round(3)
    d = d.copy()
    d[0, :4] = 0.0  # invalid pixels stay 0
    return d


def _mm(i: int) -> np.ndarray:
    return np.round(_depth_m(i) * 1000).astype(np.uint16)


def _ingest(tmp_path: Path, rgb, depth) -> list:
    path = write_bag(tmp_path / "bag", rgbd_messages(rgb, depth))
    with RecordingFrames(path) as rf:
        return list(rf)


def _rgb(i: int) -> np.ndarray:
    return smooth_rgb(i, H, W)


COLOUR_CASES = {
    "rgb8": lambda a: a,
    "bgr8": lambda a: a[..., ::-1],
    "rgba8": lambda a: np.concatenate([a, np.full((H, W, 1), 255, np.uint8)], axis=2),
    "bgra8": lambda a: np.concatenate([a[..., ::-1], np.full((H, W, 1), 7, np.uint8)], axis=2),
}


@pytest.mark.parametrize("encoding", sorted(COLOUR_CASES))
def test_raw_colour_encodings(tmp_path: Path, encoding: str) -> None:
    make = COLOUR_CASES[encoding]
    frames = _ingest(
        tmp_path,
        lambda i, t: image_msg(t, make(_rgb(i)), encoding),
        lambda i, t: image_msg(t, _mm(i), "16UC1"),
    )
    assert len(frames) == 3
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.rgb, _rgb(i))


def test_mono8_is_grey_rgb(tmp_path: Path) -> None:
    grey = lambda i: _rgb(i)[..., 0]  # noqa: E731
    frames = _ingest(
        tmp_path,
        lambda i, t: image_msg(t, grey(i), "mono8"),
        lambda i, t: image_msg(t, _mm(i), "16UC1"),
    )
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.rgb, np.repeat(grey(i)[..., None], 3, axis=2))


def test_step_padding_and_big_endian(tmp_path: Path) -> None:
    """Rows padded beyond width*channels and big-endian 16-bit depth decode correctly."""

    def padded_rgb(i: int, t: int):
        msg = image_msg(t, _rgb(i), "rgb8")
        rows = np.zeros((H, W * 3 + 4), np.uint8)
        rows[:, : W * 3] = _rgb(i).reshape(H, -1)
        msg.step = W * 3 + 4
        msg.data = rows.ravel()
        return msg

    def big_endian_depth(i: int, t: int):
        msg = image_msg(t, _mm(i).astype(">u2"), "16UC1")
        msg.is_bigendian = 1
        return msg

    frames = _ingest(tmp_path, padded_rgb, big_endian_depth)
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.rgb, _rgb(i))
        np.testing.assert_allclose(f.depth_m, _depth_m(i), atol=1e-6)


@pytest.mark.parametrize("encoding", ["16UC1", "mono16", "32FC1"])
def test_raw_depth_encodings(tmp_path: Path, encoding: str) -> None:
    def depth(i: int, t: int):
        if encoding == "32FC1":
            d = _depth_m(i).copy()
            d[1, :3] = np.nan  # NaN is invalid, as is 0
            return image_msg(t, d, "32FC1")
        return image_msg(t, _mm(i), encoding)

    frames = _ingest(tmp_path, lambda i, t: image_msg(t, _rgb(i), "rgb8"), depth)
    for i, f in enumerate(frames):
        expected = _depth_m(i).copy()
        if encoding == "32FC1":
            expected[1, :3] = 0.0
        assert f.depth_m.dtype == np.float32
        np.testing.assert_allclose(f.depth_m, expected, atol=1e-6)


def test_compressed_jpeg_and_png_colour(tmp_path: Path) -> None:
    jpeg = {i: jpeg_bytes(_rgb(i)) for i in range(3)}
    frames = _ingest(
        tmp_path,
        lambda i, t: compressed_msg(t, jpeg[i], "rgb8; jpeg compressed bgr8"),
        lambda i, t: compressed_msg(t, png_bytes(_mm(i)), "16UC1; png compressed"),
    )
    for i, f in enumerate(frames):
        reference = np.asarray(Image.open(io.BytesIO(jpeg[i])).convert("RGB"))  # PIL's own decode
        np.testing.assert_array_equal(f.rgb, reference)
        np.testing.assert_allclose(f.depth_m, _depth_m(i), atol=1e-6)
    (tmp_path / "bag").rename(tmp_path / "old")
    frames = _ingest(
        tmp_path,
        lambda i, t: compressed_msg(t, png_bytes(_rgb(i)), "rgb8; png compressed bgr8"),
        lambda i, t: image_msg(t, _mm(i), "16UC1"),
    )
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.rgb, _rgb(i))  # PNG is lossless


def test_compressed_depth_16uc1(tmp_path: Path) -> None:
    """image_transport's compressedDepth: 12-byte ConfigHeader, then a 16-bit PNG in mm."""
    header = struct.pack("<iff", 1, 0.0, 0.0)
    frames = _ingest(
        tmp_path,
        lambda i, t: image_msg(t, _rgb(i), "rgb8"),
        lambda i, t: compressed_msg(t, header + png_bytes(_mm(i)), "16UC1; compressedDepth"),
    )
    for i, f in enumerate(frames):
        np.testing.assert_allclose(f.depth_m, _depth_m(i), atol=1e-6)


def test_compressed_depth_32fc1_inverse_quantised(tmp_path: Path) -> None:
    """32FC1 compressedDepth stores a / depth + b as uint16 (image_transport's codec)."""
    a, b = 300.0, -50.0

    def depth(i: int, t: int):
        d = _depth_m(i)
        with np.errstate(divide="ignore"):
            q = np.where(d > 0, np.round(a / d + b), 0).astype(np.uint16)
        return compressed_msg(
            t, struct.pack("<iff", 1, a, b) + png_bytes(q), "32FC1; compressedDepth png"
        )

    frames = _ingest(tmp_path, lambda i, t: image_msg(t, _rgb(i), "rgb8"), depth)
    for i, f in enumerate(frames):
        ref = _depth_m(i)
        np.testing.assert_array_equal(f.depth_m == 0, ref == 0)
        np.testing.assert_allclose(f.depth_m, ref, rtol=0.01)  # quantisation error


def test_unsupported_encoding_names_topic_and_encoding(tmp_path: Path) -> None:
    with pytest.raises(
        IngestError,
        match=r"topic /camera/color/image_raw: image encoding 'yuv422' is not supported",
    ):
        _ingest(
            tmp_path,
            lambda i, t: image_msg(t, np.zeros((H, W, 2), np.uint8), "yuv422"),
            lambda i, t: image_msg(t, _mm(i), "16UC1"),
        )
