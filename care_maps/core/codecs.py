"""How a store keeps a view's images and features, chosen by measurement.

Two encodings, told apart by a store's own columns (:func:`views_encoding`,
:func:`features_encoding`):

- :attr:`StoreEncoding.RAW_ZSTD`, what stores are written in: depth and label images as raw
  little-endian ``uint16`` in one zstd frame (level 1), colour as JPEG (the recording's own
  bytes when it sent JPEG, else encoded once at quality 95, no chroma subsampling), the
  feature map as its raw little-endian ``float16`` bytes. The image columns are already
  compressed and the features do not compress (random-looking mantissas: zstd saved 8% of
  them), so Parquet keeps those columns uncompressed and a read is a copy, not a decode.
- :attr:`StoreEncoding.PNG_LISTS`, the 0.1 store: 16-bit PNG depth and labels, colour
  re-encoded as JPEG, features as a Parquet list of ``float16`` under zstd. Still written
  and read, so the default can be measured against it side by side (``bench/ingest.py``,
  ``bench/fuse.py``) and shown to give the same maps (``tests/care/test_encodings.py``).

Measured on the 211-frame living room (640x480, one thread; ``bench/`` has the figures): a
PNG depth costs 6.9 ms to write and 3.3 ms to read, its zstd frame 1.0 ms and 0.5 ms at
1.25x the size; a 24x32x512 feature map 8.8 ms and 3.8 ms as a list, 2.3 ms and 0.5 ms as
bytes at 1.09x; a JPEG 2.8 ms to encode, nothing when the recording's own bytes are kept.

Codecs are pyarrow's (zstd) and Pillow's (PNG, JPEG): no library beyond the store's own.
Pillow is imported by the functions that use it (0.01 s): a query reads no image.
"""

from __future__ import annotations

import io
from enum import StrEnum

import numpy as np
import pyarrow as pa

__all__ = [
    "JPEG_QUALITY",
    "StoreEncoding",
    "decode_jpeg",
    "decode_png",
    "decode_u16",
    "encode_jpeg",
    "encode_png",
    "encode_u16",
    "jpeg_size",
]

JPEG_QUALITY = 95
"""Quality of the JPEGs the store encodes itself (4:4:4: colour edges stay where depth has
them)."""

_ZSTD = pa.Codec("zstd", compression_level=1)
"""Level 1: level 3 saved 5% of a depth image's bytes for 1.3x the encoding time."""


class StoreEncoding(StrEnum):
    """How a store's views and features are encoded (see the module's docstring)."""

    RAW_ZSTD = "raw-zstd"
    """Written by default: zstd-framed raw ``uint16`` images, JPEG colour, raw ``float16``."""
    PNG_LISTS = "png-lists"
    """The 0.1 store: 16-bit PNG images, JPEG colour, Parquet ``float16`` lists."""

    @property
    def image_suffix(self) -> str:
        """Suffix of the views table's depth and label columns (``depth_zstd``, ...)."""
        return "zstd" if self is StoreEncoding.RAW_ZSTD else "png"

    def encode_image(self, image: np.ndarray) -> bytes:
        """A (H, W) ``uint16`` depth or label image in this encoding."""
        if self is StoreEncoding.RAW_ZSTD:
            return encode_u16(image)
        return encode_png(image)

    def decode_image(self, data: bytes, width: int, height: int) -> np.ndarray:
        """Inverse of :meth:`encode_image` for an image of ``width`` x ``height``."""
        if self is StoreEncoding.RAW_ZSTD:
            return decode_u16(data, width, height)
        return decode_png(data)


def encode_u16(image: np.ndarray) -> bytes:
    """One zstd frame of a (H, W) ``uint16`` image's little-endian bytes, row-major."""
    raw = np.ascontiguousarray(image, dtype="<u2")
    return _ZSTD.compress(raw.data.cast("B"), asbytes=True)  # raw.data: memoryview(raw)


def decode_u16(data: bytes, width: int, height: int) -> np.ndarray:
    """Inverse of :func:`encode_u16`; the image's size comes from its view's row."""
    raw = _ZSTD.decompress(data, decompressed_size=2 * width * height)
    return np.frombuffer(raw, dtype="<u2").reshape(height, width).astype(np.uint16, copy=False)


def encode_png(image: np.ndarray) -> bytes:
    """Lossless PNG bytes of a uint8 (H, W[, 3]) or uint16 (H, W) image."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def decode_png(data: bytes) -> np.ndarray:
    """Inverse of :func:`encode_png` (16-bit PNGs come back as uint16)."""
    from PIL import Image

    img = Image.open(io.BytesIO(data))
    arr = np.asarray(img)
    return arr.astype(np.uint16, copy=False) if img.mode.startswith("I") else arr


def encode_jpeg(rgb: np.ndarray) -> bytes:
    """JPEG bytes of an (H, W, 3) ``uint8`` image, as the store encodes colour itself."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="JPEG", quality=JPEG_QUALITY, subsampling=0)
    return buf.getvalue()


def decode_jpeg(data: bytes) -> np.ndarray:
    """(H, W, 3) ``uint8`` RGB of JPEG bytes: Pillow's decoding, the one ingest decodes a
    recording's JPEG messages with, so kept bytes give back the very pixels encoded from."""
    from PIL import Image

    img = Image.open(io.BytesIO(data))
    # convert() copies even an RGB image (a sixth of the decode at 640x480)
    return np.asarray(img if img.mode == "RGB" else img.convert("RGB"))


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) of JPEG bytes from their header alone; None when they are not JPEG."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as img:
            return (int(img.width), int(img.height)) if img.format == "JPEG" else None
    except (OSError, SyntaxError, ValueError):
        return None
