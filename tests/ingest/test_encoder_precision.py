"""``care ingest --precision bfloat16``: the same CLIP checkpoint run cheaper. Its store says
so (encoder record, recorded config, fingerprint) while a float32 store keeps the record it
always had, and its features stay within :data:`MIN_COSINE` of full precision, computed here
by the float32 encoder on the views the recording holds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from care_maps.core.encoders import EncoderOptions, Precision, make_encoder
from care_maps.core.encoders.record import encoder_for_store
from care_maps.core.errors import EncoderError
from care_maps.core.frames import Frame
from care_maps.core.store import Store
from care_maps.ingest.folders.frames import open_frames
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.source import ReadOptions
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from tests.support.frames import load_livingroom

MIN_COSINE = 0.999
"""Least cosine between a cell's bfloat16 and float32 features (the tiny test CLIP gives
0.9998 and above; ViT-B/32's, in ``bench/encode.py``, its own figure)."""

QUIET = Execution(progress=False)


def _recording(root: Path, out: Path) -> Path:
    """Eight living-room views at a quarter of their size (160x120), in MCAP."""
    frames = []
    for f in load_livingroom(root, 8):
        K = f.K.copy()
        K[:2] /= 4
        K[:2, 2] = (f.K[:2, 2] - 1.5) / 4
        frames.append(Frame(f.stamp_ns, f.rgb[::4, ::4].copy(), f.depth_m[::4, ::4].copy(), K,
                            f.cam_to_world))  # fmt: skip
    return write_recording(out, frames, fmt="mcap")


def _cosines(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = a.astype(np.float64), b.astype(np.float64)
    return (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))


@pytest.mark.slow
def test_a_bfloat16_store_records_it_and_stays_near_full_precision(
    tmp_path: Path, livingroom_root: Path, save_tiny_clip, monkeypatch: pytest.MonkeyPatch
) -> None:
    rec = _recording(livingroom_root, tmp_path / "room.mcap")
    weights = str(save_tiny_clip(tmp_path / "weights", layers=2))
    stores = {}
    for precision in Precision:
        options = EncoderOptions(weights=weights, batch_size=3, precision=precision)
        config = IngestConfig(encoder="clip", encoder_options=options, vocabulary="chair,sofa")
        stores[precision] = run_ingest(rec, tmp_path / f"store-{precision}", config, run=QUIET)
    metas = {p: json.loads((s / "meta.json").read_text()) for p, s in stores.items()}
    full, cheap = metas[Precision.FLOAT32], metas[Precision.BFLOAT16]

    # the float32 store's record and config are those of a store made before the option
    assert "precision" not in full["encoder_record"]
    assert "precision" not in full["config"]["encoder_options"]
    assert cheap["encoder_record"]["precision"] == "bfloat16"
    assert cheap["config"]["encoder_options"]["precision"] == "bfloat16"
    assert cheap["fingerprint"] != full["fingerprint"]
    assert cheap["request_fingerprint"] != full["request_fingerprint"]

    # the same option again: up to date, no model loaded
    def no_model(*args: object, **kwargs: object) -> None:
        raise AssertionError("an up-to-date store loaded a model")

    monkeypatch.setattr("care_maps.ingest.pipeline.make_encoder", no_model)
    options = EncoderOptions(weights=weights, batch_size=3, precision=Precision.BFLOAT16)
    config = IngestConfig(encoder="clip", encoder_options=options, vocabulary="chair,sofa")
    run_ingest(rec, stores[Precision.BFLOAT16], config, run=QUIET)
    monkeypatch.undo()

    # the reference: the float32 encoder on the views ingest decoded
    reference = make_encoder("clip", EncoderOptions(weights=weights, batch_size=16))
    with open_frames(rec, ReadOptions()) as decoded:
        frames = list(decoded)
    expected = reference.encode_views(frames)
    features = dict(Store(stores[Precision.BFLOAT16]).iter_features())
    got = np.stack([features[i] for i in range(len(frames))])
    assert got.shape == expected.shape
    cosines = _cosines(got, expected)
    assert cosines.min() >= MIN_COSINE
    assert not np.array_equal(got, expected.astype(np.float16))  # it did run in bfloat16

    # later steps rebuild the store's encoder at its precision: crops for instance maps
    rebuilt = encoder_for_store(stores[Precision.BFLOAT16])
    crops = [f.rgb[20:90, 30:120] for f in frames]
    crop_cosines = _cosines(rebuilt.encode_crops(crops), reference.encode_crops(crops))
    assert crop_cosines.min() >= MIN_COSINE
    # and the text side stays full precision: the store's class names are the reference's
    names, text = Store(stores[Precision.BFLOAT16]).text_embeddings()
    np.testing.assert_allclose(text, reference.encode_text(names), atol=1e-6)


def test_an_encoder_without_the_precision_is_refused_in_one_line() -> None:
    options = EncoderOptions(precision=Precision.BFLOAT16)
    with pytest.raises(
        EncoderError, match=r"^--precision bfloat16: encoder 'labels' runs in float32 only$"
    ):
        make_encoder("labels", options)
