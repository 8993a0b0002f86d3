"""The vocabulary a map's columns are computed for, and its text embeddings.

By default a map uses the class names the store cached at ingest (``text.parquet``). An
override picks names from that cache; names the cache lacks are encoded by the store's own
encoder, rebuilt from the record ingest left (:mod:`care_maps.core.encoders.record`), so the text side always matches the features' space.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from care_maps.core.errors import CareError, FuseError
from care_maps.core.store import Store

__all__ = ["vocabulary_text"]


def vocabulary_text(
    store: Store, vocabulary: Sequence[str] | None = None, *, weights: Path | None = None
) -> tuple[tuple[str, ...], np.ndarray]:
    """``(names, (n, d) float32 L2-normalised embeddings)`` for ``vocabulary`` or the store's
    (``weights``: where the store's model lives now, if its directory moved)."""
    if store.table_path("text").is_file():  # a damaged or mismatched cache is an error
        cached_names, cached = store.text_embeddings()
    else:
        cached_names, cached = [], np.zeros((0, store.encoder.dim), np.float32)
    names = tuple(cached_names) if vocabulary is None else tuple(vocabulary)
    if not names:
        msg = (
            f"{store.path}: no vocabulary: the store caches no class names; "
            "pass --vocabulary NAME[,NAME...]"
        )
        raise FuseError(msg)
    index = {name: i for i, name in enumerate(cached_names)}
    missing = [name for name in names if name not in index]
    emb = np.zeros((len(names), store.encoder.dim), np.float32)
    known = [i for i, name in enumerate(names) if name in index]
    emb[known] = cached[[index[names[i]] for i in known]]
    if missing:
        emb[[names.index(m) for m in missing]] = _encode(store, missing, weights)
    norm = np.linalg.norm(emb, axis=1, keepdims=True)
    return names, emb / np.where(norm > 0, norm, 1.0)


def _encode(store: Store, names: list[str], weights: Path | None) -> np.ndarray:
    from care_maps.core.encoders.record import text_encoder_for_store

    encoder_name = store.encoder.name
    try:
        return np.asarray(
            text_encoder_for_store(store.path, weights=weights).encode_text(names), np.float32
        )
    except (CareError, ImportError) as err:
        msg = (
            f"{store.path}: cannot embed {names} with the store's encoder {encoder_name!r} "
            f"({err}); use names the store caches or re-ingest with that vocabulary."
        )
        raise FuseError(msg) from err
