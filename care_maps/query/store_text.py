"""A store's own text side: the model that embeds free text in the space its map was built in.

:func:`care_maps.query.map.load_map` attaches one to every map it reads, and the open-vocabulary
queries (:mod:`care_maps.query.openvocab`) call it for text the vocabulary lacks. It depends on no other
query module, so reading a map and answering free text stay one-way: map, then queries.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from care_maps.core.errors import CareError, QueryError

__all__ = ["NoTextSideError", "StoreText"]


class NoTextSideError(QueryError):
    """The store's model cannot embed this text (a precomputed store without it in its text
    table): the query falls back to the sentence model. Any other failure is an error."""


class StoreText:
    """A store's own text side, built at the first free-text query and kept (CLIP loads once).

    Calling it embeds texts. It raises :class:`NoTextSideError` when the store's model has no text
    side for them, and any other :class:`~care_maps.core.errors.CareError` (moved weights, another
    version) as it is.
    """

    def __init__(self, store: Path, weights: Path | None = None) -> None:
        self.store, self.weights = Path(store), weights
        self._embed: Callable[[Sequence[str]], np.ndarray] | None = None
        self._lookup_only = False
        self.describe = "store text encoder"

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        if self._embed is None:
            from care_maps.core.encoders.record import store_record, store_text_encoder

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
