"""Streaming per-candidate sums, the state from which every measure column is computed.

Both maps fuse the same way: each view contributes weighted samples ``(candidate, w, f)``
and each candidate keeps ``W1, W2, sum w f, sum w f^2``, its view count and the pwKL sums
``S, Q, A`` of the per-view class distributions. That is O(d + n) memory per candidate, one
pass over the views, and no per-view state kept in memory (the per-view tables on disk keep
the samples for recomputation). Scatter-adds go through ``torch.index_add_`` so a view's
samples are added in one call, with capacity grown by doubling as new candidates appear.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import torch

from fuse.measures import PROB_FLOOR, candidate_columns, pwkl_linear, weighted_stderr

__all__ = ["CandidateSums"]


class CandidateSums:
    """Accumulates weighted per-view samples of candidates 0..size-1 (float64 throughout).

    Args:
        dim: feature dimension d.
        text: (n, d) L2-normalised text embeddings of the vocabulary.
        scale: logit scale s of the class distributions.
        capacity: initial number of candidates allocated; grows on demand.
    """

    def __init__(self, dim: int, text: np.ndarray, scale: float, *, capacity: int = 1024) -> None:
        self.dim = int(dim)
        self.text = torch.as_tensor(np.asarray(text, dtype=np.float64))
        if self.text.ndim != 2 or self.text.shape[1] != self.dim:
            msg = f"text embeddings of shape {tuple(self.text.shape)}, expected (n, {self.dim})"
            raise ValueError(msg)
        self.scale = float(scale)
        self.size = 0
        n = self.text.shape[0]
        cap = max(int(capacity), 1)
        f64 = torch.float64
        self._W1 = torch.zeros(cap, dtype=f64)
        self._W2 = torch.zeros(cap, dtype=f64)
        self._count = torch.zeros(cap, dtype=torch.int64)
        self._sum_wf = torch.zeros(cap, self.dim, dtype=f64)
        self._sum_wf2 = torch.zeros(cap, self.dim, dtype=f64)
        self._S = torch.zeros(cap, n, dtype=f64)
        self._Q = torch.zeros(cap, n, dtype=f64)
        self._A = torch.zeros(cap, n, dtype=f64)

    _FIELDS = ("_W1", "_W2", "_count", "_sum_wf", "_sum_wf2", "_S", "_Q", "_A")

    def ensure(self, size: int) -> None:
        """Make room for candidates 0..size-1 (new ones start at zero)."""
        cap = self._W1.shape[0]
        if size > cap:
            new_cap = max(size, 2 * cap)
            for name in self._FIELDS:
                old = getattr(self, name)
                grown = torch.zeros((new_cap, *old.shape[1:]), dtype=old.dtype)
                grown[:cap] = old
                setattr(self, name, grown)
        self.size = max(self.size, int(size))

    def add(
        self,
        ids: np.ndarray,
        weights: np.ndarray,
        features: np.ndarray,
        dots: np.ndarray | None = None,
    ) -> None:
        """Add one sample per row: candidate ``ids`` (k,), weights (k,), features (k, d).

        Each row counts as one view of its candidate, so pass one row per (view, candidate).
        ``dots`` (k, n), the features' dot products with the text embeddings, skips the
        (k x d x n) product when the caller has them cheaper (the grid does).
        """
        ids_t = torch.as_tensor(np.asarray(ids, dtype=np.int64))
        if ids_t.numel() == 0:
            return
        self.ensure(int(ids_t.max()) + 1)
        w = torch.as_tensor(np.asarray(weights, dtype=np.float64))
        f = torch.as_tensor(np.asarray(features, dtype=np.float64))
        wf = w[:, None] * f
        self._W1.index_add_(0, ids_t, w)
        self._W2.index_add_(0, ids_t, w * w)
        self._count.index_add_(0, ids_t, torch.ones_like(ids_t))
        self._sum_wf.index_add_(0, ids_t, wf)
        self._sum_wf2.index_add_(0, ids_t, wf * f)
        dots_t = f @ self.text.T if dots is None else torch.as_tensor(np.asarray(dots, np.float64))
        P = torch.softmax(self.scale * dots_t, dim=1)
        a = torch.log(P.clamp_min(PROB_FLOOR))
        self._S.index_add_(0, ids_t, P * a)
        self._Q.index_add_(0, ids_t, P)
        self._A.index_add_(0, ids_t, a)

    @property
    def nbytes(self) -> int:
        """Bytes held by the accumulators: O(capacity x (d + n)), independent of the views."""
        return sum(getattr(self, name).nbytes for name in self._FIELDS)

    @property
    def num_views(self) -> np.ndarray:
        return self._count[: self.size].numpy()

    @property
    def weight(self) -> np.ndarray:
        """(N,) W1, the summed sample weights."""
        return self._W1[: self.size].numpy()

    def fused(self) -> np.ndarray:
        """(N, d) weighted mean per-view feature (not yet re-normalised)."""
        W1 = self._W1[: self.size, None].clamp_min(np.finfo(np.float64).tiny)
        return (self._sum_wf[: self.size] / W1).numpy()

    def stderr(self) -> np.ndarray:
        s = slice(0, self.size)
        return weighted_stderr(
            self._W1[s].numpy(),
            self._W2[s].numpy(),
            self._sum_wf[s].numpy(),
            self._sum_wf2[s].numpy(),
            self.num_views,
        )

    def pwkl(self) -> np.ndarray:
        s = slice(0, self.size)
        return pwkl_linear(
            self._S[s].numpy(), self._Q[s].numpy(), self._A[s].numpy(), self.num_views
        )

    def columns(self) -> pa.Table:
        """The common candidate columns (:func:`fuse.measures.candidate_columns`)."""
        return candidate_columns(
            self.fused(),
            self.text.numpy(),
            self.scale,
            num_views=self.num_views,
            stderr=self.stderr(),
            pwkl=self.pwkl(),
        )
