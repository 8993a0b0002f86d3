"""Open-vocabulary queries: text that is not a class of the map joins the vocabulary.

A map's confidence is a softmax over its vocabulary. Text the vocabulary lacks ("a red mug on
the table") is embedded by the store's *own* text side (CLIP's text tower for ``clip`` stores,
the precomputed text table, MiniLM for ``labels``) and added as one more class for that query,
as OpenMask3D scores a query against its class list: ``log_norm`` gains the query's term, and
the candidates' class rankings (the top-k category set) gain the query at its place. The
uncertainty columns (entropy, stderr, pwKL) stay the map's own, computed over the vocabulary.

When the store's model has no text side for arbitrary text (a ``precomputed`` store whose text
table lacks the query), the text is mapped to the nearest vocabulary classes by the offline
sentence model instead (:func:`query.text.resolve_text`), and the mapping says so.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from care.errors import CareError, QueryError
from query.map import CandidateMap
from query.text import TextMatch, resolve_text

__all__ = ["NoTextSideError", "StoreText", "join_vocabulary", "open_query"]

_CHUNK = 1 << 16
"""Candidates per block when ranking the query among every class (bounds the (N, n) logits)."""


class NoTextSideError(QueryError):
    """The store's model cannot embed this text (a precomputed store without it in its text
    table): the query falls back to the sentence model. Any other failure is an error."""


class StoreText:
    """A store's own text side, built at the first free-text query and kept (CLIP loads once).

    Calling it embeds texts. It raises :class:`NoTextSideError` when the store's model has no text
    side for them, and any other :class:`~care.errors.CareError` (moved weights, another
    version) as it is.
    """

    def __init__(self, store: Path, weights: Path | None = None) -> None:
        self.store, self.weights = Path(store), weights
        self._embed: Callable[[Sequence[str]], np.ndarray] | None = None
        self._lookup_only = False
        self.describe = "store text encoder"

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        if self._embed is None:
            from care.encoders.record import store_record, store_text_encoder

            record = store_record(self.store, weights=self.weights)
            embed = store_text_encoder(self.store, weights=self.weights)
            if embed is None:
                msg = f"{self.store}: the store's {record.name} encoder has no text table"
                raise NoTextSideError(msg)
            self._embed, self._lookup_only = embed, record.name == "precomputed"
            self.describe = f"{record.name} text encoder"
        try:
            return self._embed(texts)
        except CareError as err:
            if self._lookup_only:  # the text table lacks this text
                raise NoTextSideError(str(err)) from err
            raise


def _query_rank(cmap: CandidateMap, q_logit: np.ndarray) -> np.ndarray:
    """(N,) how many vocabulary classes score strictly above the query, per candidate."""
    scaled = cmap.text * np.float32(cmap.logit_scale)
    rank = np.empty(cmap.num_candidates, np.int64)
    for lo in range(0, cmap.num_candidates, _CHUNK):
        hi = min(lo + _CHUNK, cmap.num_candidates)
        logits = cmap.features[lo:hi] @ scaled.T
        rank[lo:hi] = (logits > q_logit[lo:hi, None]).sum(axis=1)
    return rank


def join_vocabulary(cmap: CandidateMap, name: str, embedding: np.ndarray) -> CandidateMap:
    """``cmap`` with one more class, ``name``, whose text embedding is ``embedding`` (d,)."""
    emb = np.asarray(embedding, np.float32).reshape(-1)
    if emb.shape[0] != cmap.features.shape[1]:
        msg = (
            f"the query embedding has dimension {emb.shape[0]}, the map's features "
            f"{cmap.features.shape[1]}; the store's text encoder does not match its features"
        )
        raise QueryError(msg)
    emb = emb / max(float(np.linalg.norm(emb)), 1e-12)
    q_logit = (cmap.features @ emb) * np.float32(cmap.logit_scale)
    log_norm = np.logaddexp(cmap.log_norm, q_logit).astype(np.float32)
    new_id = len(cmap.vocabulary)
    top = cmap.top_classes
    width = min(top.shape[1] + 1, new_id + 1) if top.ndim == 2 else 0
    rank = _query_rank(cmap, q_logit)
    joined = np.empty((cmap.num_candidates, width), np.int16)
    if width:
        cols = np.arange(width)[None, :]
        r = np.minimum(rank, width)[:, None]
        before = np.take_along_axis(top, np.minimum(cols, top.shape[1] - 1), axis=1)
        after = np.take_along_axis(top, np.clip(cols - 1, 0, top.shape[1] - 1), axis=1)
        joined[:] = np.where(cols < r, before, np.where(cols == r, new_id, after))
    return dataclasses.replace(
        cmap,
        vocabulary=(*cmap.vocabulary, name),
        text=np.vstack([cmap.text, emb[None]]),
        log_norm=log_norm,
        top_classes=joined,
    )


def open_query(
    cmap: CandidateMap,
    text: str,
    embed: Callable[[Sequence[str]], np.ndarray] | None = None,
) -> tuple[CandidateMap, TextMatch]:
    """The map to ask and the class that ``text`` names in it.

    A vocabulary class (case-insensitive) is itself. Other text joins the vocabulary through
    ``embed`` (default: the map's :attr:`~query.map.CandidateMap.text_encoder`, the store's own
    text side); without one, or when it cannot embed the text, the
    text maps to the nearest classes by the sentence model (only when the model has no text side
    for it, :class:`NoTextSideError`; a broken model is an error). ``TextMatch.method`` says which.
    """
    if not text.strip():
        msg = "empty query text; name an object or describe it"
        raise QueryError(msg)
    key = text.strip().lower()
    for i, name in enumerate(cmap.vocabulary):
        if name.strip().lower() == key:
            return cmap, TextMatch(text, (i,), (name,), (1.0,), "vocabulary")
    embed = embed if embed is not None else cmap.text_encoder
    if embed is not None:
        try:
            emb = np.asarray(embed([text]), np.float32).reshape(-1)
        except NoTextSideError:
            emb = None
        if emb is not None:
            joined = join_vocabulary(cmap, text.strip(), emb)
            unit = joined.text[-1]
            sims = cmap.text @ unit
            near = np.argsort(-sims, kind="stable")[:3]
            names = (text.strip(), *(cmap.vocabulary[i] for i in near))
            scores = (1.0, *(float(sims[i]) for i in near))
            ids = (len(cmap.vocabulary), *(int(i) for i in near))
            return joined, TextMatch(
                text,
                ids,
                names,
                scores,
                f"joins the vocabulary [{getattr(embed, 'describe', 'text encoder')}]",
            )
    return cmap, resolve_text(cmap, text)
