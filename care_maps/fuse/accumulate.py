"""Streaming per-candidate statistics, the state from which every measure column is computed.

Both maps fuse the same way: each view contributes weighted samples ``(candidate, w, f)``.
Each candidate keeps, in float32 unless told otherwise:

- the weighted running mean ``mu`` (d) and sum of squared deviations ``M2`` (d) of its
  per-view features, merged one sample at a time by Welford's / Chan's update
  (``delta = f - mu; mu += delta w / W; M2 += delta^2 w W_old / W``), so
  ``sigma_k^2 = M2_k / W1`` never subtracts two large sums: views that agree to 1e-4 keep
  their spread to float32 precision, where ``sum w f^2 / W1 - mu^2`` would lose it;
- the mean class distribution ``Pbar`` (n) and mean log-distribution ``abar`` (n) of the
  per-view class distributions (float64: their errors enter ``C`` to first order), and one
  number ``C = sum_j sum_y (P_j - Pbar)
  (a_j - abar)``, updated the same way. It is the linear pwKL identity of docs/method.md in its
  stable streaming form: ``sum_y [m S_y - Q_y A_y] = m C`` (a co-moment), so ``D = C / (m-1)``;
  the S, Q, A sums collapse to one number plus two means per candidate;
- ``W1, W2`` (float64) and the view count.

At d = 512 and n = 100 that is 8 d + 16 n + 32 = 5,728 bytes per candidate (the float64
sums it replaces took 12.5 KB). One pass over the views, no per-view state in memory (a
recompute streams the grid's views again, or reads the instance map's per-view features).

A sample of a candidate already seen in the same call is merged after the earlier one
(calls stream views in order; :func:`care_maps.fuse.recompute.sums_from_views` passes many views at
once), so the result never depends on how the samples were batched.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pyarrow as pa

from care_maps.fuse.measures import (
    PROB_FLOOR,
    candidate_columns,
    pwkl_comoment,
    stderr_from_moments,
)
from care_maps.fuse.welford import merge_moments

__all__ = ["COLUMN_CHUNK", "CandidateSums"]

COLUMN_CHUNK = 4096
"""Candidates per chunk when the state becomes map columns (bounds the float64 temporaries)."""


class CandidateSums:
    """Streaming statistics of candidates 0..size-1 (see the module docstring).

    Args:
        dim: feature dimension d.
        text: (n, d) L2-normalised text embeddings of the vocabulary.
        scale: logit scale s of the class distributions.
        capacity: initial number of candidates allocated; grows on demand (without a
            ``limit``, or where the limit's reservation was refused).
        limit: most candidates this state will hold (growth never allocates beyond it).
            Given, the tables are reserved at the limit at once: ``np.zeros`` of that size
            is address space whose pages the kernel maps, zeroed, only when a row is first
            written, so resident memory still follows the candidates seen, and the state
            is never copied or re-zeroed as it grows (each growth step of a 79k-cell floor
            took a stall of its own).
        dtype: precision of the per-channel mean and M2 (float32; float64 for a reference).
    """

    def __init__(
        self,
        dim: int,
        text: np.ndarray,
        scale: float,
        *,
        capacity: int = 4096,
        dtype: type = np.float32,
        limit: int | None = None,
    ) -> None:
        self.dim = int(dim)
        self.text = np.asarray(text, dtype=np.float64)
        if self.text.ndim != 2 or self.text.shape[1] != self.dim:
            msg = f"text embeddings of shape {self.text.shape}, expected (n, {self.dim})"
            raise ValueError(msg)
        self.scale = float(scale)
        self.size = 0
        self.limit = None if limit is None else max(int(limit), 1)
        d, n = self.dim, self.text.shape[0]
        self.num_classes = n
        cap = max(min(int(capacity), self.limit or int(capacity)), 1)
        widths = ((2 * d, dtype), (2 * n, np.float64), (4, np.float64))
        # per candidate: [mu (d) | M2 (d)], [Pbar (n) | abar (n)], [W1, W2, views, C]
        try:  # reserved up to the limit: zeroed pages the kernel maps on first touch
            self._tables = tuple(np.zeros((self.limit or cap, w), t) for w, t in widths)
        except (MemoryError, ValueError):  # address space refused (or beyond numpy's
            # largest array, for a budget of exabytes): grow on demand instead
            self._tables = tuple(np.zeros((cap, w), t) for w, t in widths)

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The state of candidates ``0..size-1`` (views of the tables, not copies): what
        :meth:`restored` continues from, so a grid adds views later without its earlier
        views (:mod:`care_maps.fuse.grid_state`)."""
        return tuple(table[: self.size] for table in self._tables)  # type: ignore[return-value]

    @classmethod
    def restored(
        cls,
        text: np.ndarray,
        scale: float,
        state: tuple[np.ndarray, np.ndarray, np.ndarray],
        *,
        limit: int | None = None,
    ) -> CandidateSums:
        """The sums whose :meth:`state` was ``state``, for the vocabulary embeddings ``text``
        and logit scale ``scale`` it was made with: merging more samples into it gives what
        merging every sample from the start gives, bit for bit (the same operations on the
        same numbers, in the same order)."""
        moments = state[0]
        size = int(moments.shape[0])
        sums = cls(
            moments.shape[1] // 2,
            text,
            scale,
            capacity=max(size, 1),
            dtype=moments.dtype.type,
            limit=None if limit is None else max(limit, size),
        )
        sums.ensure(size)
        for table, saved in zip(sums._tables, state, strict=True):
            if table.shape[1] != saved.shape[1] or table.dtype != saved.dtype:
                msg = f"saved state of shape {saved.shape} {saved.dtype}, expected (N, {table.shape[1]}) {table.dtype}"
                raise ValueError(msg)
            table[:size] = saved
        return sums

    @classmethod
    def bytes_per_candidate(cls, dim: int, num_classes: int, dtype: type = np.float32) -> int:
        """Streaming state per candidate: what a memory budget divides by."""
        return 2 * dim * np.dtype(dtype).itemsize + 2 * num_classes * 8 + 4 * 8

    def ensure(self, size: int) -> None:
        """Make room for candidates 0..size-1 (new ones start at zero)."""
        cap = self._tables[0].shape[0]
        if size > cap:
            # in place: realloc moves large blocks without copying, so growing often is cheap
            # and a small step leaves little capacity zeroed (touched) but never used
            grown = max(size, cap + cap // 4)
            if self.limit is not None:
                grown = max(size, min(grown, self.limit))
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
        weights = np.asarray(weights, dtype=np.float64)
        features = np.asarray(features)
        order = np.argsort(ids, kind="stable")
        sorted_ids = ids[order]
        repeat = sorted_ids[1:] == sorted_ids[:-1]
        if not repeat.any():
            self._merge(ids, weights, features, dots)
            return
        # r-th sample of each candidate in round r: every round holds distinct candidates
        starts = np.flatnonzero(np.r_[True, ~repeat])
        occurrence = np.arange(k) - np.repeat(starts, np.diff(np.r_[starts, k]))
        rounds = np.empty(k, np.int64)
        rounds[order] = occurrence
        for r in range(int(occurrence.max()) + 1):
            rows = np.flatnonzero(rounds == r)
            self._merge(
                ids[rows], weights[rows], features[rows], None if dots is None else dots[rows]
            )

    def _merge(
        self, ids: np.ndarray, w: np.ndarray, features: np.ndarray, dots: np.ndarray | None
    ) -> None:
        """Chan's merge of one sample into each of the distinct candidates ``ids``."""
        moments, classes, scalars = self._tables
        n = self.num_classes
        old = scalars[ids]  # (k, 4) gathered
        w_old = old[:, 0]
        w_new = w_old + w
        share = np.divide(w, w_new, out=np.zeros_like(w), where=w_new > 0)
        # a candidate's first sample is its mean (M2 stays 0): written, not merged
        seen = old[:, 2] > 0
        fresh = np.flatnonzero(~seen)
        merge = np.flatnonzero(seen)
        dtype = moments.dtype
        merge_moments(
            moments,
            ids,
            np.ascontiguousarray(features, dtype=dtype),
            seen,
            share.astype(dtype),
            (share * w_old).astype(dtype),
        )
        # the view's class distribution P and a = log max(P, floor) by a stable softmax, in
        # the precision of the dot products (the grid passes float32 ones)
        given = dots is not None
        logits = np.array(dots) if given else np.asarray(features, np.float64) @ self.text.T
        logits *= self.scale
        logits -= logits.max(axis=1, keepdims=True)
        P = np.exp(logits)
        total = P.sum(axis=1, keepdims=True)
        P /= total
        logits -= np.log(total)
        a = np.maximum(logits, np.float32(np.log(PROB_FLOOR)), out=logits)
        m_old = old[:, 2]
        m_new = m_old + 1.0
        # [P | a] in one float64 buffer: a fresh candidate's means (as for mu, written: its
        # rows were never touched, and reading them first would fault each page in twice)
        pa_rows = np.concatenate([P, a], axis=1, dtype=np.float64)
        if fresh.size:
            classes[ids[fresh]] = pa_rows if fresh.size == ids.size else pa_rows[fresh]
        if merge.size:
            every = merge.size == ids.size
            rows = ids if every else ids[merge]
            crow = classes[rows]
            delta = pa_rows if every else pa_rows[merge]  # [P - Pbar | a - abar], in place
            delta -= crow
            m_o, m_n = (m_old, m_new) if every else (m_old[merge], m_new[merge])
            # co-moment: C += m_old / m_new * (P - Pbar) . (a - abar) (0 for a fresh one)
            old[merge, 3] += np.einsum("ij,ij->i", delta[:, :n], delta[:, n:]) * (m_o / m_n)
            delta /= m_n[:, None]
            crow += delta
            classes[rows] = crow
        old[:, 0] = w_new
        old[:, 1] += w * w
        old[:, 2] = m_new
        scalars[ids] = old

    @property
    def nbytes(self) -> int:
        """Bytes allocated for the state: O(capacity x (d + n)), independent of the views
        (with a ``limit``, reserved: resident only as far as candidates were written)."""
        return sum(b.nbytes for b in self._tables)

    @property
    def num_views(self) -> np.ndarray:
        return self._tables[2][: self.size, 2].astype(np.int64)

    @property
    def weight(self) -> np.ndarray:
        """(N,) W1, the summed sample weights."""
        return self._tables[2][: self.size, 0].copy()  # a view would dangle once it grows

    def fused(self, rows: slice | None = None) -> np.ndarray:
        """(N, d) weighted mean per-view feature (not yet re-normalised)."""
        rows = rows or slice(0, self.size)
        return self._tables[0][rows, : self.dim]

    def stderr(self, rows: slice | None = None) -> np.ndarray:
        rows = rows or slice(0, self.size)
        s = self._tables[2][rows]
        return stderr_from_moments(s[:, 0], s[:, 1], self._tables[0][rows, self.dim :], s[:, 2])

    def pwkl(self, rows: slice | None = None) -> np.ndarray:
        rows = rows or slice(0, self.size)
        s = self._tables[2][rows]
        return pwkl_comoment(s[:, 3], s[:, 2])

    def iter_columns(
        self, chunk: int = COLUMN_CHUNK, first_id: int = 0, *, with_log_confidence: bool = False
    ) -> Iterator[pa.Table]:
        """The common candidate columns, ``chunk`` candidates at a time, in id order;
        ``first_id`` is the map's id of this state's candidate 0 (a bounded-memory pass).

        Each chunk's float64 temporaries (the re-normalised features, the (chunk, n) class
        distributions) are freed before the next, so turning the state into columns never
        holds more than one chunk of them.
        """
        for lo in range(0, self.size, max(int(chunk), 1)):
            rows = slice(lo, min(lo + chunk, self.size))
            yield candidate_columns(
                self.fused(rows),
                self.text,
                self.scale,
                num_views=self._tables[2][rows, 2],
                stderr=self.stderr(rows),
                pwkl=self.pwkl(rows),
                first_id=first_id + lo,
                with_log_confidence=with_log_confidence,
            )

    def columns(self) -> pa.Table:
        """The common candidate columns (:func:`care_maps.fuse.measures.candidate_columns`)."""
        chunks = list(self.iter_columns())
        if not chunks:
            return candidate_columns(
                np.zeros((0, self.dim)),
                self.text,
                self.scale,
                num_views=np.zeros(0),
                stderr=np.zeros(0),
                pwkl=np.zeros(0),
            )
        return pa.concat_tables(chunks).combine_chunks()
