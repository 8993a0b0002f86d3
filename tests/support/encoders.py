"""A tiny real encoder for ingest and query tests (no model, no weights)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from care_maps.core.encoders import Encoder, RecordingContext, l2_normalise
from care_maps.core.frames import Frame


class TinyEncoder(Encoder):
    """A real (non-mock) encoder: per 4x4-pixel cell, the L2-normalised mean colour plus 1.

    Text side: a fixed colour per class name, so the test can check the cached embeddings.
    """

    name = "tiny"
    version = "1"
    dim = 4

    def __init__(self) -> None:
        self.prepared_with: tuple[str, ...] | None = None

    def prepare(self, context: RecordingContext) -> None:
        self.prepared_with = context.label_names

    def encode_views(self, frames: Sequence[Frame]) -> np.ndarray:
        maps = []
        for f in frames:
            h, w = f.height // 4, f.width // 4
            cells = f.rgb[: h * 4, : w * 4].reshape(h, 4, w, 4, 3).mean(axis=(1, 3)) / 255.0
            maps.append(np.concatenate([cells, np.ones((h, w, 1))], axis=-1))
        return l2_normalise(np.asarray(maps, np.float32))

    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        emb = np.array([[len(n), 1.0, 0.0, 1.0] for n in names], np.float32)
        return l2_normalise(emb)
