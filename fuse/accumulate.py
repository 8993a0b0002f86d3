"""Streaming per-candidate sums, the state from which every measure column is computed.

Both maps fuse the same way: each view contributes weighted samples ``(candidate, w, f)``
and each candidate keeps ``W1, W2, sum w f, sum w f^2``, its view count and the pwKL sums
``S, Q, A`` of the per-view class distributions. That is O(d + n) memory per candidate, one
pass over the views, and no per-view state kept in memory (the per-view tables on disk keep
the samples for recomputation). A view's samples are added to three float64 tables (the
two feature sums and the scalar/pwKL sums) with one ``torch.index_add_`` each, from
reused contiguous buffers; capacity grows by a quarter as new candidates appear.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import torch

from fuse.measures import PROB_FLOOR, candidate_columns, pwkl_linear, weighted_stderr

__all__ = ["CandidateSums"]


class CandidateSums:
    """Accumulates weighted per-view samples of candidates 0..size-1 (float64 throughout).

    Float64 because the measures subtract sums: ``sum w f^2 / W1 - mu^2`` and
    ``m S - Q A`` lose about as many digits as the views agree.

    Args:
        dim: feature dimension d.
        text: (n, d) L2-normalised text embeddings of the vocabulary.
        scale: logit scale s of the class distributions.
        capacity: initial number of candidates allocated; grows on demand.
    """

    def __init__(self, dim: int, text: np.ndarray, scale: float, *, capacity: int = 1024) -> None:
        self.dim = int(dim)
        self.text = np.asarray(text, dtype=np.float64)
        if self.text.ndim != 2 or self.text.shape[1] != self.dim:
            msg = f"text embeddings of shape {self.text.shape}, expected (n, {self.dim})"
            raise ValueError(msg)
        self.scale = float(scale)
        self.size = 0
        d, n = self.dim, self.text.shape[0]
        cap = max(int(capacity), 1)
        # per candidate: sum w f, sum w f^2, and [W1, W2, views, S (n), Q (n), A (n)]
        self._tables = (np.zeros((cap, d)), np.zeros((cap, d)), np.zeros((cap, 3 + 3 * n)))
        self._S, self._Q, self._A = (slice(3 + i * n, 3 + (i + 1) * n) for i in range(3))
        # per-view scratch, reused: fresh buffers every view cost page faults
        self._scratch = (np.empty((0, d)), np.empty((0, d)), np.empty((0, 3 + 3 * n)))

    def ensure(self, size: int) -> None:
        """Make room for candidates 0..size-1 (new ones start at zero)."""
        cap = self._tables[0].shape[0]
        if size > cap:
            # in place: realloc moves large blocks without copying, so growing often is cheap
            # and a small step leaves little capacity zeroed (touched) but never used
            grown = max(size, cap + cap // 4)
            for table in self._tables:
                table.resize((grown, table.shape[1]), refcheck=False)
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
        ids = np.asarray(ids, dtype=np.int64)
        k = ids.size
        if k == 0:
            return
        self.ensure(int(ids.max()) + 1)
        if self._scratch[0].shape[0] < k:
            grown = max(k, self._scratch[0].shape[0] * 5 // 4)
            self._scratch = tuple(np.empty((grown, b.shape[1])) for b in self._scratch)
        f, wf, rows = (b[:k] for b in self._scratch)
        w = np.asarray(weights, dtype=np.float64)
        np.copyto(f, features)
        # contiguous operands: numpy's fast loops skip strided row slices
        index = torch.from_numpy(ids)
        np.multiply(f, w[:, None], out=wf)
        torch.from_numpy(self._tables[0]).index_add_(0, index, torch.from_numpy(wf))
        np.multiply(wf, f, out=wf)
        torch.from_numpy(self._tables[1]).index_add_(0, index, torch.from_numpy(wf))
        rows[:, 0] = w
        np.multiply(w, w, out=rows[:, 1])
        rows[:, 2] = 1.0
        # the view's class distribution P and a = log max(P, floor) by a stable softmax, in
        # the precision of the dot products (the grid passes float32 ones)
        logits = f @ self.text.T if dots is None else np.array(dots)
        logits *= self.scale
        logits -= logits.max(axis=1, keepdims=True)
        P = np.exp(logits)
        total = P.sum(axis=1, keepdims=True)
        P /= total
        logits -= np.log(total)
        a = np.maximum(logits, np.log(PROB_FLOOR), out=logits)
        rows[:, self._Q] = P
        rows[:, self._A] = a
        np.multiply(rows[:, self._Q], rows[:, self._A], out=rows[:, self._S])
        torch.from_numpy(self._tables[2]).index_add_(0, index, torch.from_numpy(rows))

    @property
    def nbytes(self) -> int:
        """Bytes held by the accumulators: O(capacity x (d + n)), independent of the views."""
        return sum(b.nbytes for b in (*self._tables, *self._scratch))

    def _column(self, columns: int | slice) -> np.ndarray:
        """W1 (0), W2 (1), views (2) or a slice of S, Q, A, for candidates 0..size-1."""
        return self._tables[2][: self.size, columns]

    @property
    def num_views(self) -> np.ndarray:
        return self._column(2).astype(np.int64)

    @property
    def weight(self) -> np.ndarray:
        """(N,) W1, the summed sample weights."""
        return self._column(0).copy()  # a view would dangle once the table grows

    def fused(self) -> np.ndarray:
        """(N, d) weighted mean per-view feature (not yet re-normalised)."""
        W1 = np.maximum(self._column(0), np.finfo(np.float64).tiny)
        return self._tables[0][: self.size] / W1[:, None]

    def stderr(self) -> np.ndarray:
        return weighted_stderr(
            self._column(0),
            self._column(1),
            self._tables[0][: self.size],
            self._tables[1][: self.size],
            self.num_views,
        )

    def pwkl(self) -> np.ndarray:
        return pwkl_linear(
            self._column(self._S), self._column(self._Q), self._column(self._A), self.num_views
        )

    def columns(self) -> pa.Table:
        """The common candidate columns (:func:`fuse.measures.candidate_columns`)."""
        return candidate_columns(
            self.fused(),
            self.text,
            self.scale,
            num_views=self.num_views,
            stderr=self.stderr(),
            pwkl=self.pwkl(),
        )
