"""Open-vocabulary queries: text that is not a class of the map joins the vocabulary.

A map's confidence is a softmax over its vocabulary. Text the vocabulary lacks ("a red mug on
the table") is embedded by the store's *own* text side (CLIP's text tower for ``clip`` stores,
the precomputed text table, MiniLM for ``labels``) and added as one more class for that query,
as OpenMask3D scores a query against its class list: the softmax's normaliser gains the
query's term, and the candidates' class rankings (the top-k category set) gain the query at
its place (:class:`QueryTarget`). The uncertainty columns (entropy, stderr, pwKL) stay the
map's own, computed over the vocabulary.

When the store's model has no text side for arbitrary text (a ``precomputed`` store whose text
table lacks the query), the text is mapped to the nearest vocabulary classes by the offline
sentence model instead (:func:`care_maps.query.text.resolve_text`), and the mapping says so.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from weakref import WeakKeyDictionary

import numpy as np

from care_maps.core.errors import QueryError
from care_maps.query.confidence import confidence as class_confidence
from care_maps.query.confidence import log_confidence as class_log_confidence
from care_maps.query.map import LOG_CONFIDENCE_CACHE, NOT_IN_TOP, CandidateMap
from care_maps.query.store_text import NoTextSideError
from care_maps.query.text import TextMatch, resolve_text

__all__ = ["QueryTarget", "open_queries", "open_query"]

_CHUNK = 1 << 16
"""Candidates per block when ranking the query among every class (bounds the (N, n) logits)."""


_VOCAB_LOGITS: WeakKeyDictionary[CandidateMap, np.ndarray] = WeakKeyDictionary()
"""Per map: (N, n) float32 vocabulary logits, kept while the map lives (batches of free-text
queries then cost one matrix-vector product each)."""


def _vocab_logits(cmap: CandidateMap, lo: int, hi: int) -> np.ndarray:
    """(hi - lo, n) ``s * f . t`` of candidates lo..hi; the whole table is kept when it fits
    :data:`~care_maps.query.map.LOG_CONFIDENCE_CACHE` entries."""
    if cmap.num_candidates * len(cmap.vocabulary) <= LOG_CONFIDENCE_CACHE:
        table = _VOCAB_LOGITS.get(cmap)
        if table is None:
            table = cmap.features @ (cmap.text * np.float32(cmap.logit_scale)).T
            _VOCAB_LOGITS[cmap] = table
        return table[lo:hi]
    return cmap.features[lo:hi] @ (cmap.text * np.float32(cmap.logit_scale)).T


def _query_rank(cmap: CandidateMap, q_logit: np.ndarray) -> np.ndarray:
    """(N,) how many vocabulary classes score strictly above the query, per candidate."""
    rank = np.empty(cmap.num_candidates, np.int64)
    for lo in range(0, cmap.num_candidates, _CHUNK):
        hi = min(lo + _CHUNK, cmap.num_candidates)
        rank[lo:hi] = (_vocab_logits(cmap, lo, hi) > q_logit[lo:hi, None]).sum(axis=1)
    return rank


@dataclass(frozen=True, eq=False)
class QueryTarget:
    """What a query asks a map for: a class of its vocabulary, or free text that joins the
    vocabulary for this query. Every path that answers a query (``care query``, ``next_goal``,
    batches) reads its confidence and category ranks here, so they agree to the bit."""

    cmap: CandidateMap
    match: TextMatch
    q_logit: np.ndarray | None = None
    """Free text: (N,) float32 ``s * f . e`` of its unit embedding e; None for a class."""
    log_norm: np.ndarray | None = None
    """Free text: (N,) float32 logsumexp over the vocabulary plus the text."""

    @classmethod
    def of_class(
        cls, cmap: CandidateMap, class_id: int, match: TextMatch | None = None
    ) -> QueryTarget:
        if not 0 <= class_id < len(cmap.vocabulary):
            msg = f"class id {class_id} is not in the vocabulary (0..{len(cmap.vocabulary) - 1})"
            raise QueryError(msg)
        name = cmap.vocabulary[class_id]
        return cls(cmap, match or TextMatch(name, (class_id,), (name,), (1.0,), "vocabulary"))

    @classmethod
    def of_text(cls, cmap: CandidateMap, match: TextMatch, embedding: np.ndarray) -> QueryTarget:
        """Free text with its embedding (d,) from the store's own text side."""
        emb = np.asarray(embedding, np.float32).reshape(-1)
        if emb.shape[0] != cmap.features.shape[1]:
            msg = (
                f"the query embedding has dimension {emb.shape[0]}, the map's features "
                f"{cmap.features.shape[1]}; the store's text encoder does not match its features"
            )
            raise QueryError(msg)
        emb = emb / np.float32(max(float(np.linalg.norm(emb)), 1e-12))
        q_logit = (cmap.features @ emb) * np.float32(cmap.logit_scale)
        log_norm = np.logaddexp(cmap.log_norm, q_logit).astype(np.float32)
        return cls(cmap, match, q_logit.astype(np.float32), log_norm)

    @property
    def free_text(self) -> bool:
        return self.q_logit is not None

    def log_confidence(self) -> np.ndarray:
        """(N,) float32 log P_c of the target (what rankings use: no ties at P = 1.0)."""
        if self.q_logit is None:
            return class_log_confidence(self.cmap, np.array([self.match.class_id]))[0]
        return np.minimum(self.q_logit - self.log_norm, 0.0)

    def confidence(self) -> np.ndarray:
        """(N,) float32 P_c of the target: softmax over the vocabulary (plus the free text)."""
        if self.q_logit is None:
            return class_confidence(self.cmap, np.array([self.match.class_id]))[0]
        return np.exp(self.log_confidence())

    def class_rank(self, limit: int | None = None) -> np.ndarray:
        """(N,) int16 place of the target in each candidate's class order (0 = top), as
        :meth:`~care_maps.query.map.CandidateMap.class_rank`; free text ranks among the vocabulary plus
        itself (before classes it ties with)."""
        if self.q_logit is None:
            return self.cmap.class_rank(np.array([self.match.class_id]), limit=limit)[0]
        top = self.cmap.top_classes
        width = (top.shape[1] if top.ndim == 2 else 0) + 1
        depth = width if limit is None else max(0, min(int(limit), width))
        rank = _query_rank(self.cmap, self.q_logit)
        return np.where(rank < depth, rank, NOT_IN_TOP).astype(np.int16)


def open_query(
    cmap: CandidateMap,
    text: str | int,
    embed: Callable[[Sequence[str]], np.ndarray] | None = None,
) -> QueryTarget:
    """What ``text`` (or a class id) asks ``cmap`` for.

    A vocabulary class (case-insensitive) is itself. Other text joins the vocabulary through
    ``embed`` (default: the map's :attr:`~care_maps.query.map.CandidateMap.text_encoder`, the store's own
    text side, :class:`care_maps.query.store_text.StoreText`). Only when that model has no text side for it (:class:`NoTextSideError`) does
    the text map to the nearest classes by the sentence model; a broken model is an error.
    ``QueryTarget.match.method`` says which.
    """
    if not isinstance(text, str):
        return QueryTarget.of_class(cmap, int(text))
    return open_queries(cmap, [text], embed)[0]


def open_queries(
    cmap: CandidateMap,
    texts: Sequence[str],
    embed: Callable[[Sequence[str]], np.ndarray] | None = None,
) -> list[QueryTarget]:
    """:func:`open_query` for many texts, embedding the free ones in one call."""
    out: list[QueryTarget | None] = [None] * len(texts)
    free: list[int] = []
    for i, text in enumerate(texts):
        if not text.strip():
            msg = "empty query text; name an object or describe it"
            raise QueryError(msg)
        class_id = cmap.find_class(text)
        if class_id is None:
            free.append(i)
        else:
            out[i] = QueryTarget.of_class(cmap, class_id)
    embed = embed if embed is not None else cmap.text_encoder
    embeddings = None
    if free and embed is not None:
        try:
            embeddings = np.asarray(embed([texts[i] for i in free]), np.float32)
        except NoTextSideError:
            embeddings = None
    how = f"joins the vocabulary [{getattr(embed, 'describe', 'text encoder')}]"
    for row, i in enumerate(free):
        if embeddings is None:
            match = resolve_text(cmap, texts[i])
            out[i] = QueryTarget.of_class(cmap, match.class_id, match)
            continue
        emb = embeddings[row].reshape(-1)
        unit = emb / max(float(np.linalg.norm(emb)), 1e-12)
        sims = cmap.text @ unit if len(unit) == cmap.text.shape[1] else np.zeros(0)
        near = np.argsort(-sims, kind="stable")[:3]
        match = TextMatch(
            texts[i],
            (len(cmap.vocabulary), *(int(j) for j in near)),
            (texts[i].strip(), *(cmap.vocabulary[j] for j in near)),
            (1.0, *(float(sims[j]) for j in near)),
            how,
        )
        out[i] = QueryTarget.of_text(cmap, match, emb)
    return out  # type: ignore[return-value]
