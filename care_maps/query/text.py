"""Free text to vocabulary classes: a robot is asked for "couch", the map knows "sofa".

A query that names a class of the map's vocabulary (case-insensitive) is that class. Any other
text is embedded and matched to the nearest class names by cosine similarity, using the
encoder's own text side when it has one (CLIP: the same space the map was built in), or else
the offline sentence model (for encoders such as ``labels`` whose text side only knows the
vocabulary). The mapping is always returned so callers can report it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from care_maps.core.errors import QueryError
from care_maps.query.map import CandidateMap

__all__ = ["TextEmbedder", "TextMatch", "resolve_text", "sentence_embedder"]

TextEmbedder = Callable[[Sequence[str]], np.ndarray]
"""Texts -> (n, d) embeddings; rows are normalised here before the cosine."""


@dataclass(frozen=True)
class TextMatch:
    """How a query text was mapped to classes of the vocabulary."""

    text: str
    class_ids: tuple[int, ...]
    """Nearest classes, best first; the first is the query's target class."""
    names: tuple[str, ...]
    scores: tuple[float, ...]
    """Cosine similarity of the text to each class name (1.0 for an exact name)."""
    method: str
    """``vocabulary`` (an exact class name), ``map text`` (the map's own text space via
    ``embed``) or ``sentence:<backend>`` (a sentence model against the class names; the
    backend is ``minilm``, ``hashed`` or ``custom``)."""

    @property
    def class_id(self) -> int:
        return self.class_ids[0]

    def describe(self) -> str:
        """One line for logs: ``'somewhere to sit' -> chair (0.61), sofa (0.58) [sentence]``."""
        pairs = ", ".join(f"{n} ({s:.2f})" for n, s in zip(self.names, self.scores, strict=True))
        return f"{self.text!r} -> {pairs} [{self.method}]"


def _unit(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / np.where(norm > 0, norm, 1.0)


def sentence_embedder() -> TextEmbedder:
    """The offline sentence model of ``care_maps.core.encoders.sentence`` as a :data:`TextEmbedder`."""
    try:
        from care_maps.core.encoders.sentence import sentence_model
    except ImportError as err:
        msg = "free-text queries need care_maps.core.encoders.sentence (the offline sentence model); name a vocabulary class instead"
        raise QueryError(msg) from err
    model = sentence_model()
    embed = lambda texts: model.embed(list(texts))  # noqa: E731 - the embedder is a plain callable
    embed.backend = model.backend  # type: ignore[attr-defined]
    return embed


def resolve_text(
    cmap: CandidateMap,
    text: str,
    *,
    embed: TextEmbedder | None = None,
    same_space: bool = False,
    top: int = 3,
) -> TextMatch:
    """Map ``text`` to the nearest classes of ``cmap``'s vocabulary.

    ``embed`` embeds texts; with ``same_space=True`` it is the map encoder's text side and the
    query is compared with the map's stored text embeddings, otherwise (a sentence model) with
    the embeddings of the class names made by ``embed`` itself. Default: the sentence model.
    """
    if not text.strip():
        msg = "empty query text; name an object class"
        raise QueryError(msg)
    key = text.strip().lower()
    for i, name in enumerate(cmap.vocabulary):
        if name.strip().lower() == key:
            return TextMatch(text, (i,), (name,), (1.0,), "vocabulary")
    if embed is None:
        embed, same_space = sentence_embedder(), False
    query = _unit(embed([text]))[0]
    classes = cmap.text if same_space else embed(list(cmap.vocabulary))
    if query.shape[0] != np.asarray(classes).shape[1]:
        msg = f"query embedding of dimension {query.shape[0]} does not match the class embeddings ({np.asarray(classes).shape[1]})"
        raise QueryError(msg)
    scores = _unit(classes) @ query
    order = np.argsort(-scores, kind="stable")[: max(1, top)]
    return TextMatch(
        text,
        tuple(int(i) for i in order),
        tuple(cmap.vocabulary[i] for i in order),
        tuple(float(scores[i]) for i in order),
        "map text" if same_space else f"sentence:{getattr(embed, 'backend', 'custom')}",
    )
