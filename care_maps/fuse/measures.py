"""The paper's uncertainty measures as pure, vectorised functions on arrays.

Every function here works on a batch of N candidates (grid cells or instances) at once and
follows ``docs/method.md`` to the letter:

- class distribution ``P = softmax(s * f . t)`` with the logit scale ``s`` (CLIP's 100);
- entropy ``H = -sum_y P log P``;
- channel-averaged weighted standard error from streaming sums, with ``m_eff = W1^2 / W2``;
- mean pairwise symmetric KL by the linear identity over the sums ``S, Q, A`` (the pairwise
  form is kept as :func:`pwkl_pairwise`, the reference the tests compare against).

Both view-spread measures are ``+inf`` below two views: one view says nothing about
agreement, and ``+inf`` sorts such candidates last under the *min* rules that use them.

:func:`candidate_columns` turns fused features and these measures into the Arrow columns that
``cells.parquet`` and ``instances.parquet`` share, so the grid and instance maps agree on
names, types and meaning.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np
import pyarrow as pa
from scipy.special import logsumexp

from care_maps.core.keys import ENCODER_NAME_KEY, LOGIT_SCALE_KEY, VOCABULARY_KEY
from care_maps.fuse.config import DEFAULT_LOGIT_SCALE

__all__ = [
    "DEFAULT_LOGIT_SCALE",
    "MAX_TOP_CLASSES",
    "MEASURE_COLUMNS",
    "PROB_FLOOR",
    "candidate_columns",
    "candidate_metadata",
    "class_distribution",
    "class_logits",
    "entropy",
    "list_column",
    "log_confidence",
    "log_norm",
    "pwkl_comoment",
    "pwkl_linear",
    "pwkl_pairwise",
    "pwkl_terms",
    "stderr_from_moments",
    "to_float16",
    "top_classes",
    "weighted_stderr",
]

MEASURE_COLUMNS = ("confidence", "entropy", "stderr", "pwkl", "num_views")
"""A candidate's columns that say how sure the map is of it, in display order."""

PROB_FLOOR = 1e-12
"""Probabilities are clamped here before a log, so a class with P = 0 stays finite."""

MAX_TOP_CLASSES = 100
"""``top_classes`` keeps the first min(n, 100) classes: enough for every top-k criterion."""


def class_logits(features: np.ndarray, text: np.ndarray, scale: float) -> np.ndarray:
    """(N, n) float64 logits ``s * f . t_y`` of (N, d) features against (n, d) text embeddings."""
    features = np.asarray(features, dtype=np.float64)
    text = np.asarray(text, dtype=np.float64)
    return scale * (features @ text.T)


def log_norm(
    features: np.ndarray, text: np.ndarray, scale: float = DEFAULT_LOGIT_SCALE
) -> np.ndarray:
    """(N,) ``logsumexp_y(s * f . t_y)``: with it, ``P[y] = exp(s * f . t_y - log_norm)``.

    Stored per candidate so a query can score any class of the vocabulary from the fused
    feature alone, without materialising the whole (N, n) distribution.
    """
    return logsumexp(class_logits(features, text, scale), axis=1)


def log_confidence(logits: np.ndarray, lnorm: np.ndarray) -> np.ndarray:
    """(N, n) float64 ``log P_c[y]`` that keeps its precision where ``P_c[y]`` is near 1.

    ``logits - log_norm`` is exact to ~1e-16 absolute, plenty for every class but a row's
    most likely one, whose log-probability can be -1e-30: there it is
    ``-log1p(sum_{z != y} exp(l_z - l_y))`` (docs/method.md), so near-certain candidates keep
    distinct values instead of tying at 0 (probability 1).
    """
    logits = np.asarray(logits, np.float64)
    out = logits - np.asarray(lnorm, np.float64)[:, None]
    if out.shape[1] == 0 or out.shape[0] == 0:
        return out
    rows = np.arange(len(logits))
    top = logits.argmax(axis=1)
    rest = np.exp(logits - logits[rows, top][:, None])
    rest[rows, top] = 0.0
    out[rows, top] = -np.log1p(rest.sum(axis=1))
    return out


def class_distribution(
    features: np.ndarray, text: np.ndarray, scale: float = DEFAULT_LOGIT_SCALE
) -> np.ndarray:
    """(N, n) float64 softmax over the vocabulary of (N, d) features; rows sum to 1."""
    logits = class_logits(features, text, scale)
    return np.exp(logits - logsumexp(logits, axis=1, keepdims=True))


def entropy(P: np.ndarray) -> np.ndarray:
    """(N,) Shannon entropy (nats) of the rows of P; ``0 log 0 = 0``."""
    P = np.asarray(P, dtype=np.float64)
    logp = np.log(np.where(P > 0, P, 1.0))
    return -np.sum(P * logp, axis=1)


def weighted_stderr(
    W1: np.ndarray,
    W2: np.ndarray,
    sum_wf: np.ndarray,
    sum_wf2: np.ndarray,
    num_views: np.ndarray,
) -> np.ndarray:
    """(N,) channel-averaged standard error from streaming sums; ``+inf`` below two views.

    ``sigma_k^2 = sum w f_k^2 / W1 - mu_k^2`` (clamped at 0 against rounding), then
    ``SE = mean_k sigma_k / sqrt(m_eff)`` with ``m_eff = W1^2 / W2``. With all weights 1
    this is the plain (population) form the instance map uses.
    """
    W1 = np.asarray(W1, dtype=np.float64)
    W2 = np.asarray(W2, dtype=np.float64)
    num_views = np.asarray(num_views)
    ok = (num_views >= 2) & (W1 > 0) & (W2 > 0)
    w1 = np.where(ok, W1, 1.0)[:, None]
    mu = np.asarray(sum_wf, dtype=np.float64) / w1
    var = np.clip(np.asarray(sum_wf2, dtype=np.float64) / w1 - mu * mu, 0.0, None)
    m_eff = np.where(ok, W1 * W1 / np.where(ok, W2, 1.0), 1.0)
    se = np.sqrt(var).mean(axis=1) / np.sqrt(m_eff)
    return np.where(ok, se, np.inf)


def stderr_from_moments(
    W1: np.ndarray, W2: np.ndarray, M2: np.ndarray, num_views: np.ndarray
) -> np.ndarray:
    """(N,) :func:`weighted_stderr` from Welford/Chan moments: ``sigma_k^2 = M2_k / W1``.

    ``M2_k = sum_j w_j (f_jk - mu_k)^2`` is accumulated from deviations
    (:class:`care_maps.fuse.accumulate.CandidateSums`), so nothing cancels here and float32 ``M2``
    keeps views that agree to 1e-4 at float32 precision.
    """
    W1 = np.asarray(W1, dtype=np.float64)
    W2 = np.asarray(W2, dtype=np.float64)
    num_views = np.asarray(num_views)
    ok = (num_views >= 2) & (W1 > 0) & (W2 > 0)
    w1 = np.where(ok, W1, 1.0)
    sigma = np.sqrt(np.clip(np.asarray(M2, np.float64), 0.0, None) / w1[:, None])
    m_eff = np.where(ok, W1 * W1 / np.where(ok, W2, 1.0), 1.0)
    se = sigma.mean(axis=1) / np.sqrt(m_eff) if sigma.shape[1] else np.zeros(len(W1))
    return np.where(ok, se, np.inf)


def pwkl_comoment(C: np.ndarray, num_views: np.ndarray) -> np.ndarray:
    """(N,) mean pairwise symmetric KL from the co-moment ``C``; ``+inf`` below two views.

    ``C = sum_j sum_y (P_j[y] - Pbar[y]) (a_j[y] - abar[y])`` over a candidate's m views is
    the linear identity's ``sum_y [m S_y - Q_y A_y]`` divided by m (expand the product), so
    ``D = C / (m - 1)``. Streamed by Welford's update it subtracts no large sums.
    """
    m = np.asarray(num_views, dtype=np.float64)
    ok = m >= 2
    D = np.asarray(C, np.float64) / np.where(ok, m - 1.0, 1.0)
    return np.where(ok, np.clip(D, 0.0, None), np.inf)


def pwkl_terms(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-view contributions ``(P log P, P, log P)`` of (k, n) distributions to S, Q, A.

    Summing these over the views of a candidate gives the S, Q, A of :func:`pwkl_linear`;
    the log uses probabilities clamped at :data:`PROB_FLOOR`.
    """
    P = np.asarray(P, dtype=np.float64)
    a = np.log(np.clip(P, PROB_FLOOR, None))
    return P * a, P, a


def pwkl_linear(S: np.ndarray, Q: np.ndarray, A: np.ndarray, num_views: np.ndarray) -> np.ndarray:
    """(N,) mean pairwise symmetric KL by the O(m n) identity; ``+inf`` below two views.

    ``D = 1/(m(m-1)) * sum_y [m S_y - Q_y A_y]`` with ``S = sum_j P_j log P_j``,
    ``Q = sum_j P_j``, ``A = sum_j log P_j``: streamable with O(n) memory per candidate,
    where the paper's pairwise form needs O(m^2) (and ran out of memory on large scenes).
    Tiny negative results from rounding (views that agree) are clamped to 0.
    """
    m = np.asarray(num_views, dtype=np.float64)
    ok = m >= 2
    total = np.sum(m[:, None] * np.asarray(S, np.float64) - np.asarray(Q, np.float64) * A, axis=1)
    denom = np.where(ok, m * (m - 1), 1.0)
    return np.where(ok, np.clip(total / denom, 0.0, None), np.inf)


def pwkl_pairwise(P_views: Sequence[np.ndarray]) -> np.ndarray:
    """(N,) the paper's pairwise mean symmetric KL, one (m, n) array per candidate.

    The reference for :func:`pwkl_linear` (O(m^2 n) time and memory per candidate): only
    tests and the benchmark call it.
    """
    out = np.empty(len(P_views), dtype=np.float64)
    for i, P in enumerate(P_views):
        P = np.asarray(P, dtype=np.float64)
        m = P.shape[0]
        if m < 2:
            out[i] = np.inf
            continue
        a = np.log(np.clip(P, PROB_FLOOR, None))
        # kl[j, l] = KL(P_j || P_l) = sum_y P_j (a_j - a_l)
        kl = np.sum(P * a, axis=1)[:, None] - P @ a.T
        sym = 0.5 * (kl + kl.T)
        out[i] = np.sum(np.triu(sym, k=1)) * 2.0 / (m * (m - 1))
    return out


def top_classes(P: np.ndarray, limit: int = MAX_TOP_CLASSES) -> tuple[np.ndarray, np.ndarray]:
    """The first min(n, limit) classes of each row of P by descending probability.

    Returns ``(classes (N, k) int16, probs (N, k) float64)``; ties keep the lower class id
    first (a stable sort), so rankings are reproducible.
    """
    P = np.asarray(P, dtype=np.float64)
    k = min(P.shape[1], limit)
    order = np.argsort(-P, axis=1, kind="stable")[:, :k]
    return order.astype(np.int16), np.take_along_axis(P, order, axis=1)


def list_column(values: np.ndarray, value_type: pa.DataType) -> pa.Array:
    """(N, k) array as an Arrow ``list<value_type>`` column without a Python loop."""
    n, k = values.shape
    offsets = pa.array(np.arange(n + 1, dtype=np.int32) * k, pa.int32())
    flat = pa.array(np.ascontiguousarray(values).ravel(), value_type)
    return pa.ListArray.from_arrays(offsets, flat)


def to_float16(x: np.ndarray) -> np.ndarray:
    """float16 copy of an array, converted by torch (several times faster than numpy's)."""
    import torch

    return torch.from_numpy(np.ascontiguousarray(x)).to(torch.float16).numpy()


def _normalise(x: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    return x / np.where(norm > 0, norm, 1.0)


def candidate_columns(
    fused: np.ndarray,
    text: np.ndarray,
    scale: float = DEFAULT_LOGIT_SCALE,
    *,
    num_views: np.ndarray,
    stderr: np.ndarray,
    pwkl: np.ndarray,
    top: int = MAX_TOP_CLASSES,
    first_id: int = 0,
    with_log_confidence: bool = False,
) -> pa.Table:
    """The columns every map table shares, for N candidates, in row order.

    ``fused`` is the (N, d) weighted mean of each candidate's per-view features (it is
    re-normalised here); ``stderr`` and ``pwkl`` come from :func:`weighted_stderr` and
    :func:`pwkl_linear` (or their streaming forms). ``first_id``: candidate id of the first
    row, for a map written in chunks. ``with_log_confidence`` adds ``log_confidence``, a
    fixed-size list of :func:`log_confidence` per class (float32), for the query sidecar. Confidence of class y is ``exp(s * feature . t_y - log_norm)``;
    ``top_classes`` / ``top_probs`` summarise P_c for the top-k category criterion.
    """
    # Measures are computed from the float16 feature as stored, so a reader's
    # exp(s * feature . t_y - log_norm) sums to 1 over the vocabulary.
    fused16 = to_float16(_normalise(np.asarray(fused, dtype=np.float64)))
    fused = fused16.astype(np.float64)
    n_cand = fused.shape[0]
    logits = class_logits(fused, text, scale)
    lnorm = logsumexp(logits, axis=1) if logits.shape[1] else np.zeros(n_cand)
    P = np.exp(logits - lnorm[:, None])
    classes, probs = top_classes(P, top)
    extra = {}
    if with_log_confidence and logits.shape[1]:
        logp = log_confidence(logits, lnorm).astype(np.float32)
        extra["log_confidence"] = pa.FixedSizeListArray.from_arrays(
            pa.array(logp.ravel()), logits.shape[1]
        )
    return pa.table(
        {
            "candidate_id": pa.array(np.arange(first_id, first_id + n_cand, dtype=np.int32)),
            "num_views": pa.array(np.asarray(num_views, dtype=np.int32)),
            "feature": list_column(fused16, pa.float16()),
            "log_norm": pa.array(lnorm.astype(np.float32)),
            "top_classes": list_column(classes, pa.int16()),
            "top_probs": list_column(to_float16(probs), pa.float16()),
            "entropy": pa.array(entropy(P).astype(np.float32)),
            "stderr": pa.array(np.asarray(stderr, dtype=np.float32)),
            "pwkl": pa.array(np.asarray(pwkl, dtype=np.float32)),
            **extra,
        }
    )


def candidate_metadata(
    vocabulary: Sequence[str], logit_scale: float, encoder_name: str
) -> dict[bytes, bytes]:
    """Schema metadata every map table carries (the schema version is added on write)."""
    return {
        VOCABULARY_KEY: json.dumps(list(vocabulary)).encode(),
        LOGIT_SCALE_KEY: repr(float(logit_scale)).encode(),
        ENCODER_NAME_KEY: encoder_name.encode(),
    }
