"""The store's encodings give the same maps: the default (``raw-zstd``, :mod:`care_maps.core.codecs`)
against the 0.1 store (``png-lists``), built from the same recordings by ``care ingest``
and fused by ``care fuse``.

Where the inputs are lossless (the living room's frames written as raw ``rgb8``) every map
table is equal value for value; from a JPEG recording (the bundled sample's, the living
room's written as JPEG), which the default store keeps as the recording sent it while the
0.1 store encoded it again, every value but the points' and cells' colours is equal, and
the colours lie within JPEG's error. A map
records the checksums of the store it came from (:data:`care_maps.fuse.keys.STORE_KEY`), which
differ by design, and nothing else of it.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from care_maps.core.codecs import StoreEncoding
from care_maps.fuse.keys import STORE_KEY
from tests.support.frames import load_livingroom

STORE_OWN = frozenset({"views.parquet", "features.parquet", "text.parquet"})
COLOURS = ("r", "g", "b")


def _maps(store: Path) -> dict[str, object]:
    """Every map table of ``store``, its schema metadata without the store's stamp."""
    tables = {}
    for path in sorted(store.rglob("*.parquet")):
        if path.name in STORE_OWN:
            continue
        table = pq.read_table(path)
        meta = {k: v for k, v in (table.schema.metadata or {}).items() if k != STORE_KEY}
        tables[str(path.relative_to(store))] = table.replace_schema_metadata(meta)
    return tables


def _build(run_cli, recording: Path, store: Path, encoding: StoreEncoding, *extra: str) -> None:
    code, _, err = run_cli(
        "ingest", recording, "--out", store, "--store-encoding", encoding.value, *extra
    )
    assert code == 0, err
    for kind in ("grid", "instances"):
        code, _, err = run_cli("fuse", kind, store)
        assert code == 0, err


def _assert_equal_maps(old: Path, new: Path, *, colours_exact: bool = True) -> None:
    a, b = _maps(old), _maps(new)
    assert a.keys() == b.keys()
    assert "cells.parquet" in a
    assert "instances.parquet" in a
    for name, table in a.items():
        other = b[name]
        assert table.schema == other.schema, name
        for column in table.column_names:
            if not colours_exact and column in COLOURS:
                continue
            assert table.column(column).equals(other.column(column)), (name, column)


@pytest.mark.slow
def test_sample_maps_equal_value_for_value(tmp_path: Path, run_cli) -> None:
    """The bundled sample world (JPEG colour, labels encoder): both maps, every table."""
    recording = Path(__file__).parents[2] / "care_maps" / "data" / "sample" / "scene_000.mcap"
    stores = {e: tmp_path / e.value for e in StoreEncoding}
    for encoding, store in stores.items():
        _build(run_cli, recording, store, encoding, "--encoder", "labels")
    old, new = stores[StoreEncoding.PNG_LISTS], stores[StoreEncoding.RAW_ZSTD]
    _assert_equal_maps(old, new, colours_exact=False)
    _assert_close_colours(old, new)


def _assert_close_colours(old: Path, new: Path) -> None:
    """The cells' colours from a second JPEG (quality 95) against the recording's own."""
    colours = [pq.read_table(s / "cells.parquet", columns=list(COLOURS)) for s in (old, new)]
    a, b = (np.stack([t.column(c).to_numpy() for c in COLOURS]).astype(int) for t in colours)
    assert np.abs(a - b).mean() < 2.0
    assert np.abs(a - b).max() <= 40


def _livingroom(root: Path) -> list:
    from care_maps.core.frames import Frame

    frames = []
    for f in load_livingroom(root, 40)[::5]:
        K = f.K.copy()
        K[:2] /= 2
        K[:2, 2] = (f.K[:2, 2] - 0.5) / 2
        frames.append(Frame(f.stamp_ns, f.rgb[::2, ::2].copy(), f.depth_m[::2, ::2].copy(), K,
                            f.cam_to_world))  # fmt: skip
    return frames


@pytest.mark.slow
@pytest.mark.parametrize("jpeg", [False, True], ids=["raw-rgb8", "jpeg"])
def test_livingroom_maps_equal(
    tmp_path: Path, run_cli, livingroom_root: Path, save_tiny_clip, jpeg: bool
) -> None:
    """Third-party frames through the real MCAP writer, features from a CLIP checkpoint."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from care_maps.ingest.write import TOPICS, write_recording

    recording = write_recording(
        tmp_path / "living.mcap", _livingroom(livingroom_root), fmt="mcap", compressed_rgb=jpeg
    )
    weights = save_tiny_clip(tmp_path / "weights", layers=2)
    stores = {e: tmp_path / e.value for e in StoreEncoding}
    for encoding, store in stores.items():
        _build(
            run_cli, recording, store, encoding,
            "--encoder", "clip", "--weights", weights, "--vocabulary", "chair,sofa,table",
        )  # fmt: skip
    old, new = stores[StoreEncoding.PNG_LISTS], stores[StoreEncoding.RAW_ZSTD]
    _assert_equal_maps(old, new, colours_exact=not jpeg)
    kept = pq.read_table(new / "views.parquet", columns=["rgb_jpeg"]).column(0).to_pylist()
    if not jpeg:
        return
    # the default store holds the recording's own bytes, as the mcap library reads them back
    with recording.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        sent = [
            bytes(decoded.data)
            for *_, decoded in reader.iter_decoded_messages(topics=[TOPICS["rgb_compressed"]])
        ]
    assert len(sent) == 8
    assert kept == sent
    _assert_close_colours(old, new)
    first = np.asarray(Image.open(io.BytesIO(kept[0])))
    assert first.shape == (240, 320, 3)


def test_a_folder_of_jpegs_is_kept_as_its_files(tmp_path: Path, livingroom_root: Path) -> None:
    """The living room as Redwood publishes it (JPEG colour files): the store holds each
    file's bytes, and they decode to the very pixels ingest read."""
    from care_maps.core.store import Store, StoreWriter
    from care_maps.ingest.folders.frames import open_frames

    with open_frames(livingroom_root) as frames, StoreWriter(tmp_path / "s", None) as writer:
        read = []
        for frame in frames:
            read.append(frame)
            writer.add(frame)
            if len(read) == 3:
                break
        assert writer.kept_jpeg == 3
        writer.commit({"source": "livingroom"})
    files = sorted((livingroom_root / "image").glob("*.jpg"))[:3]
    kept = pq.read_table(tmp_path / "s" / "views.parquet", columns=["rgb_jpeg"]).column(0)
    assert kept.to_pylist() == [f.read_bytes() for f in files]
    for (_, back), frame, file in zip(
        Store(tmp_path / "s").iter_frames(), read, files, strict=True
    ):
        assert np.array_equal(back.rgb, frame.rgb)
        assert np.array_equal(back.rgb, np.asarray(Image.open(file).convert("RGB")))
