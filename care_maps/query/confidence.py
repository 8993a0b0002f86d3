"""Confidence of map candidates for target classes, batched over queries as array operations.

``P_c[y] = exp(s * f_c . t_y - log_norm_c)``. For maps whose (classes x candidates) table
fits :data:`care_maps.query.map.LOG_CONFIDENCE_CACHE`, the log-confidence of every class is computed
once per map and a query is a row gather; larger maps multiply against the *distinct* query
classes only, so a batch of 1,000 queries over 200 classes is one (N, d) x (d, <=200)
product, not 1,000 of them.
"""

from __future__ import annotations

import numpy as np

from care_maps.core.errors import QueryError
from care_maps.query.map import CandidateMap

__all__ = ["confidence", "log_confidence", "rank_by_confidence"]


def _class_ids(cmap: CandidateMap, class_ids: np.ndarray | int) -> np.ndarray:
    ids = np.atleast_1d(np.asarray(class_ids, dtype=np.int64))
    if ids.size and (ids.min() < 0 or ids.max() >= len(cmap.vocabulary)):
        msg = f"class id out of range 0..{len(cmap.vocabulary) - 1}: {ids.min()}..{ids.max()}"
        raise QueryError(msg)
    return ids


def log_confidence(cmap: CandidateMap, class_ids: np.ndarray | int) -> np.ndarray:
    """(Q, N) float32 ``log P_c[y]``: ranks like :func:`confidence` but keeps near-certain
    candidates apart (P = 1 - 1e-9 and 1 - 1e-12 are both 1.0 in float32, their logs are
    not). A map with a query sidecar reads one row per class: no (N, d) product."""
    ids = _class_ids(cmap, class_ids)
    if cmap.log_confidence_rows is not None:
        return cmap.log_confidence_of(ids)
    table = cmap.log_confidence_table
    if table is not None:
        return table[ids]
    uniq, inverse = np.unique(ids, return_inverse=True)
    out = cmap.log_confidence_of(uniq)
    return out[inverse] if len(uniq) < len(ids) or not np.array_equal(uniq, ids) else out


def confidence(cmap: CandidateMap, class_ids: np.ndarray | int) -> np.ndarray:
    """(Q, N) float32 confidence P_c[y] of every candidate for each query class ``y``."""
    ids = _class_ids(cmap, class_ids)
    table = cmap.log_confidence_table
    if table is not None:
        out = table[ids]
        return np.exp(out, out=out)
    uniq, inverse = np.unique(ids, return_inverse=True)
    out = np.exp(cmap.log_confidence_of(uniq))
    return out[inverse] if len(uniq) < len(ids) or not np.array_equal(uniq, ids) else out


def rank_by_confidence(conf: np.ndarray) -> np.ndarray:
    """(Q, N) candidate ids in descending confidence, ties by lower id (a stable sort)."""
    return np.argsort(-np.atleast_2d(conf), axis=1, kind="stable")
