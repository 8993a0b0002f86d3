"""The encoder plugin interface: image side for ingest, text side for query.

An encoder turns views into dense feature maps (fh, fw, d), L2-normalised per cell, and
class names into text embeddings (n, d) in the same space. Everything downstream (fuse,
query, replan) is encoder-agnostic: it sees only these arrays.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any, cast

import numpy as np

from care_maps.core.errors import EncoderError
from care_maps.core.fingerprint import config_fields
from care_maps.core.frames import Frame
from care_maps.core.store import BATCH_SIZE, EncoderInfo

__all__ = [
    "CLIP_LOGIT_SCALE",
    "DEFAULT_PERCEPTION",
    "Encoder",
    "EncoderOptions",
    "Precision",
    "RecordingContext",
    "l2_normalise",
    "recorded_options",
]

CLIP_LOGIT_SCALE = 100.0
"""CLIP's learned logit scale (clipped at 100 in training, Radford et al. 2021): the ``s`` of
softmax(s * f . t) that the maps use by default and the sample world is measured at."""


DEFAULT_PERCEPTION = "default"
"""The ``labels`` encoder's perception preset when none is given (the sample world's
:class:`care_maps.world.perception.model.PerceptionPreset` lists them)."""


class Precision(StrEnum):
    """Number format an encoder's image side computes in: the same checkpoint run cheaper.
    ``bench/encode.py`` measures each against full precision (speed, and the cosine and
    top-1 class agreement of dense features and crops)."""

    FLOAT32 = "float32"
    """Full precision, the checkpoint's own."""
    BFLOAT16 = "bfloat16"
    """The vision tower's matrix products in bfloat16 (``torch.autocast``), where the CPU
    (AVX-512 BF16) or GPU has it; features are normalised in float32. The text side stays
    full precision, so class names and free-text queries embed as in a float32 store."""


@dataclass(frozen=True)
class EncoderOptions:
    """Options any encoder may read; each encoder documents which ones it uses."""

    weights: str | None = None
    """Local directory of weights, or a checkpoint id where downloads are possible (clip)."""
    device: str | None = None
    """torch device; default CUDA when available, else CPU."""
    batch_size: int = BATCH_SIZE
    """Views encoded per forward pass."""
    precomputed: Path | None = None
    """Parquet file of per-view features keyed by image stamp (precomputed)."""
    perception: str = DEFAULT_PERCEPTION
    """Perception-model preset of the ``labels`` encoder (``default`` or ``ideal``)."""
    seed: int = 0
    """Seed of any randomness in the encoder (the labels model's biases and noise)."""
    precision: Precision = Precision.FLOAT32
    """Number format of the encoder's image side: bfloat16 (clip) runs the same checkpoint
    faster, near full precision (docs/benchmarks.md, "Encoder at ingest")."""


RECORDED_WHEN_SET = ("precision",)
"""Fields of :class:`EncoderOptions` a store records (in its fingerprint, its ``meta.json``
config and its encoder record) only when they differ from their defaults: fields added after
stores were made, so that those stores keep their bytes and stay current."""


HOW_OPTIONS = ("device", "batch_size")
"""Fields of :class:`EncoderOptions` that say how the model runs, not what features it makes:
left out of a store's fingerprint, and free to differ between the runs of one store."""


def feature_options(options: EncoderOptions) -> dict[str, Any]:
    """:func:`recorded_options` without :data:`HOW_OPTIONS`: what the features depend on."""
    return {k: v for k, v in recorded_options(options).items() if k not in HOW_OPTIONS}


def recorded_options(options: EncoderOptions) -> dict[str, Any]:
    """``options`` as the plain values a store records, without the fields of
    :data:`RECORDED_WHEN_SET` at their defaults."""
    default = EncoderOptions()
    unset = [n for n in RECORDED_WHEN_SET if getattr(options, n) == getattr(default, n)]
    return config_fields(options, unset)


@dataclass(frozen=True)
class RecordingContext:
    """What ingest knows about the recording before the first view is encoded."""

    source: Path
    label_names: tuple[str, ...] = ()
    """Class names indexed by the values of the recording's ``class`` label image, if any."""


class Encoder(ABC):
    """A vision-language feature encoder."""

    name: str = ""
    version: str = "0"
    dim: int = 0
    supports_crops: bool = False
    precisions: frozenset[Precision] = frozenset({Precision.FLOAT32})
    """The :class:`Precision` values the encoder runs in; :func:`make_encoder` refuses others."""

    @classmethod
    def for_text(cls, options: EncoderOptions) -> Encoder:
        """An instance that only needs to embed text (a free-text query on a built map).

        Default: the whole encoder. A model with separate towers (CLIP) overrides it to
        load the text tower alone, so a query does not pay for the image side it never
        runs; :meth:`encode_views` may then fail, :attr:`version` and :attr:`dim` must
        stay those of the whole encoder (the store's record is checked against them)."""
        # a registered encoder class takes one EncoderOptions (this base declares no __init__)
        return cast("Callable[[EncoderOptions], Encoder]", cls)(options)

    def prepare(self, context: RecordingContext) -> None:  # noqa: B027 - optional hook
        """Called once per recording before :meth:`encode_views`; default does nothing."""

    @abstractmethod
    def encode_views(self, frames: Sequence[Frame]) -> np.ndarray:
        """Dense feature maps (B, fh, fw, d) float32, each cell L2-normalised."""

    def prepare_views(self, frames: Sequence[Frame]) -> Any:
        """What :meth:`encode_views` does before its forward pass (resizing, normalising),
        for ingest to run on a background thread ahead of the model; :meth:`encode_prepared`
        takes the result. Default: the frames as they are (all the work is the forward)."""
        return frames

    def encode_prepared(self, prepared: Any) -> np.ndarray:
        """:meth:`encode_views` of what :meth:`prepare_views` returned: the same maps."""
        return self.encode_views(prepared)

    @abstractmethod
    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        """Text embeddings (n, d) float32, L2-normalised, in the image features' space."""

    def encode_crops(self, crops: Sequence[np.ndarray]) -> np.ndarray:
        """Whole-crop features (B, d) of (h, w, 3) uint8 crops; only where supported."""
        msg = f"encoder {self.name!r} cannot encode crops; use --features masked"
        raise EncoderError(msg)

    def info(self, vocabulary: Sequence[str] = ()) -> EncoderInfo:
        return EncoderInfo(self.name, self.version, self.dim, tuple(vocabulary))


def l2_normalise(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Unit vectors along ``axis``; zero vectors stay zero."""
    norm = np.linalg.norm(x, axis=axis, keepdims=True)
    return x / np.where(norm > 0, norm, 1.0)
