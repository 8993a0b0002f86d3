"""Ingest prepares the next batch for the model while this one is in it
(:func:`care_maps.ingest.pipeline._stream`): the store is the one the sequential path
(``read_ahead=0``) writes, and the features are the encoder's own, called directly."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from care_maps.core.encoders import EncoderOptions, make_encoder
from care_maps.core.frames import Frame
from care_maps.core.store import Store
from care_maps.ingest.folders.frames import open_frames
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.source import ReadOptions
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from tests.support.encoders import TinyEncoder
from tests.support.frames import load_livingroom, synthetic_frames

WAIT_S = 20.0
"""How long the next batch may take to start preparing (it starts at once when overlapped)."""


def _small_livingroom(root: Path, count: int) -> list[Frame]:
    """Living-room frames at a quarter of their size (160x120), as the outputs test makes them."""
    frames = []
    for f in load_livingroom(root, count):
        K = f.K.copy()
        K[:2] /= 4
        K[:2, 2] = (f.K[:2, 2] - 1.5) / 4
        frames.append(Frame(f.stamp_ns, f.rgb[::4, ::4].copy(), f.depth_m[::4, ::4].copy(), K,
                            f.cam_to_world))  # fmt: skip
    return frames


@pytest.mark.slow
def test_overlapped_features_equal_the_sequential_and_the_encoders_own(
    tmp_path: Path, livingroom_root: Path, save_tiny_clip
) -> None:
    rec = write_recording(
        tmp_path / "room.mcap", _small_livingroom(livingroom_root, 10), fmt="mcap"
    )
    weights = save_tiny_clip(tmp_path / "weights", layers=2)
    options = EncoderOptions(weights=str(weights), batch_size=3)  # 10 views: 3 + 3 + 3 + 1
    config = IngestConfig(encoder="clip", encoder_options=options, vocabulary="chair,sofa")
    stores = {
        depth: Store(
            run_ingest(rec, tmp_path / f"store-{depth}", config,
                       run=Execution(read_ahead=depth, progress=False))
        )
        for depth in (0, 4)
    }  # fmt: skip
    sequential = dict(stores[0].iter_features())
    overlapped = dict(stores[4].iter_features())
    assert sorted(overlapped) == list(range(10))
    for view_id, feature in sequential.items():
        np.testing.assert_array_equal(overlapped[view_id], feature)
    # reference: the encoder called directly on the frames ingest decoded, all at once
    encoder = make_encoder("clip", EncoderOptions(weights=str(weights), batch_size=16))
    with open_frames(rec, ReadOptions()) as decoded:
        expected = encoder.encode_views(list(decoded)).astype(np.float16)
    for view_id, feature in overlapped.items():
        np.testing.assert_array_equal(feature, expected[view_id])
    names, text = stores[4].text_embeddings()
    np.testing.assert_array_equal(text, stores[0].text_embeddings()[1])
    np.testing.assert_allclose(text, encoder.encode_text(names), atol=1e-6)


class _Watched(TinyEncoder):
    """Records, for each batch, whether the next batch began preparing while this one was
    in the forward pass (each forward waits up to :data:`WAIT_S` for it)."""

    def __init__(self, batches: int) -> None:
        super().__init__()
        self.started = [threading.Event() for _ in range(batches + 1)]
        self.prepared = 0
        self.threads: set[str] = set()
        self.overlapped: list[bool] = []

    def prepare_views(self, frames: Sequence[Frame]) -> Any:
        self.threads.add(threading.current_thread().name)
        self.started[self.prepared].set()
        self.prepared += 1
        return list(frames)

    def encode_prepared(self, prepared: Any) -> np.ndarray:
        forward = len(self.overlapped)
        last = forward == len(self.started) - 2
        self.overlapped.append(last or self.started[forward + 1].wait(WAIT_S))
        return self.encode_views(prepared)


def test_the_next_batch_is_prepared_during_the_forward_pass(tmp_path: Path) -> None:
    frames = synthetic_frames(8)
    rec = write_recording(tmp_path / "r.mcap", frames, fmt="mcap")
    config = IngestConfig(encoder_options=EncoderOptions(batch_size=2))
    watched = _Watched(batches=4)
    run_ingest(rec, tmp_path / "store", config, run=Execution(progress=False), encoder=watched)
    assert watched.overlapped == [True] * 4
    assert threading.current_thread().name not in watched.threads
    # the store holds the encoder's features of every view, in order
    expected = TinyEncoder().encode_views(frames).astype(np.float16)
    features = dict(Store(tmp_path / "store").iter_features())
    np.testing.assert_array_equal(np.stack([features[i] for i in range(8)]), expected)


class _Threads(TinyEncoder):
    """Notes the torch threads its text side and its forward pass run on."""

    def __init__(self) -> None:
        super().__init__()
        self.threads: dict[str, set[int]] = {"text": set(), "forward": set()}

    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        import torch

        self.threads["text"].add(torch.get_num_threads())
        return super().encode_text(names)

    def encode_prepared(self, prepared: Any) -> np.ndarray:
        import torch

        self.threads["forward"].add(torch.get_num_threads())
        return super().encode_prepared(prepared)


def test_the_vocabularys_text_runs_on_the_forward_passs_threads(tmp_path: Path) -> None:
    """The vocabulary's prompts are a text tower's batches: they run on every core the
    forward pass has (``Work.ENCODE``), not on the ingest's own one thread."""
    from care_maps.runtime.threads import Work, thread_count

    rec = write_recording(tmp_path / "r.mcap", synthetic_frames(4), fmt="mcap")
    config = IngestConfig(encoder_options=EncoderOptions(batch_size=2), vocabulary="chair,sofa")
    encoder = _Threads()
    run_ingest(rec, tmp_path / "store", config, run=Execution(progress=False), encoder=encoder)
    assert encoder.threads == {"text": {thread_count(Work.ENCODE)},
                               "forward": {thread_count(Work.ENCODE)}}  # fmt: skip
