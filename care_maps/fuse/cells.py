"""Top-down cells: integer grid keys, a growing key -> compact id index, and per-view samples.

A cell is ``(ix, iy) = floor((x, y) / cell_size)`` in world metres, so the grid's extent
comes from the data and only occupied cells ever get an id. Ids are handed out in order of
first appearance as views stream in, so they are stable during a pass and equal the final
``candidate_id``.

:func:`view_samples` turns one view into its (view, cell) samples. Pixels that share a cell
and a feature patch are collapsed into one counted term first (runs of equal neighbours,
then the distinct (cell, patch) pairs), so the d-dimensional work grows with (cell, patch)
pairs, not pixels x d. ``bench/fuse.py`` times it against a per-pixel loop.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import sparse

from care_maps.core.errors import FuseError
from care_maps.core.frames import Frame
from care_maps.fuse.pixels import cell_tops, pixel_runs, run_sums

__all__ = ["CellIndex", "ViewSamples", "pack_cells", "unpack_cells", "view_samples"]

_OFFSET = np.int64(1 << 30)  # |ix|, |iy| < 2^30 cells keeps keys positive


def pack_cells(ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """One int64 key per (ix, iy) cell, ordered like (ix, iy) lexicographically."""
    return ((np.asarray(ix, np.int64) + _OFFSET) << np.int64(32)) | (
        np.asarray(iy, np.int64) + _OFFSET
    )


def unpack_cells(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack_cells`."""
    keys = np.asarray(keys, np.int64)
    return (keys >> np.int64(32)) - _OFFSET, (keys & np.int64(0xFFFFFFFF)) - _OFFSET


class CellIndex:
    """Packed cell keys -> compact ids 0..size-1, assigned in order of first appearance."""

    def __init__(self) -> None:
        self._keys = np.empty(0, np.int64)  # sorted
        self._ids = np.empty(0, np.int64)  # id of each sorted key

    @classmethod
    def from_keys(cls, keys: np.ndarray) -> CellIndex:
        """The index whose id i is ``keys[i]`` (a finished map's cells, in candidate order);
        the inverse of :meth:`keys_by_id`. Keys must be distinct."""
        keys = np.asarray(keys, np.int64)
        index = cls()
        order = np.argsort(keys, kind="stable")
        index._keys, index._ids = keys[order], order.astype(np.int64)
        if (index._keys[1:] == index._keys[:-1]).any():
            msg = "cell keys repeat: not the cells of one grid"
            raise FuseError(msg)
        return index

    @property
    def size(self) -> int:
        return int(self._keys.size)

    def lookup(self, keys: np.ndarray) -> np.ndarray:
        """Ids of unique ``keys`` (sorted, as ``np.unique`` returns them), adding new ones."""
        keys = np.asarray(keys, np.int64)
        pos = np.searchsorted(self._keys, keys)
        found = pos < self._keys.size
        found[found] = self._keys[pos[found]] == keys[found]
        ids = np.empty(keys.size, np.int64)
        ids[found] = self._ids[pos[found]]
        new = ~found
        ids[new] = np.arange(self.size, self.size + int(new.sum()))
        self._keys = np.insert(self._keys, pos[new], keys[new])
        self._ids = np.insert(self._ids, pos[new], ids[new])
        return ids

    def find(self, keys: np.ndarray) -> np.ndarray:
        """Ids of keys already indexed (a later pass over the same views); -1 where unknown."""
        keys = np.asarray(keys, np.int64)
        pos = np.minimum(np.searchsorted(self._keys, keys), max(self.size - 1, 0))
        if self.size == 0:
            return np.full(keys.size, -1, np.int64)
        return np.where(self._keys[pos] == keys, self._ids[pos], -1)

    def keys_by_id(self) -> np.ndarray:
        """(size,) packed key of each id."""
        out = np.empty(self.size, np.int64)
        out[self._ids] = self._keys
        return out


@dataclass(frozen=True)
class ViewSamples:
    """The (view, cell) samples of one view, one row per occupied cell (k rows).

    Attributes:
        keys: (k,) packed cell keys, sorted.
        weight: (k,) float32 summed pixel weights.
        feature: (k, d) float32 mean pixel feature, L2-normalised (derived again from the
            store by a recompute, not stored: ``cell_views.parquet`` lists the samples only).
        num_pixels: (k,) int64 pixels in the sample.
        top_z: (k,) float32 height of the highest pixel of the cell in this view.
        top_rgb: (k, 3) uint8 colour of that pixel.
        dots: (k, n) float32 ``feature . t_y`` for the vocabulary passed, else None.
    """

    keys: np.ndarray
    weight: np.ndarray
    feature: np.ndarray
    num_pixels: np.ndarray
    top_z: np.ndarray
    top_rgb: np.ndarray
    dots: np.ndarray | None = None

    @property
    def size(self) -> int:
        return int(self.keys.size)

    def take(self, rows: np.ndarray) -> ViewSamples:
        """The samples of ``rows`` only (a pass of bounded-memory fusion keeps its cells)."""
        return ViewSamples(
            self.keys[rows],
            self.weight[rows],
            self.feature[rows],
            self.num_pixels[rows],
            self.top_z[rows],
            self.top_rgb[rows],
            None if self.dots is None else self.dots[rows],
        )


def _empty(dim: int, num_classes: int | None) -> ViewSamples:
    return ViewSamples(
        np.empty(0, np.int64),
        np.empty(0, np.float32),
        np.empty((0, dim), np.float32),
        np.empty(0, np.int64),
        np.empty(0, np.float32),
        np.empty((0, 3), np.uint8),
        None if num_classes is None else np.empty((0, num_classes), np.float32),
    )


def _compact(values: np.ndarray, bound: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(values, return_inverse=True)`` for ints in [0, bound).

    A bincount over the bound when it is small next to the data (O(N), no sort), the sort of
    ``np.unique`` otherwise.
    """
    if bound <= max(4 * values.size, 1 << 16):
        seen = np.bincount(values, minlength=bound)
        uniq = np.flatnonzero(seen)
        remap = np.zeros(bound, np.int64)
        remap[uniq] = np.arange(uniq.size)
        return uniq, remap[values]
    return np.unique(values, return_inverse=True)


@lru_cache(maxsize=16)
def _patch_of_pixel(height: int, width: int, fh: int, fw: int, stride: int) -> np.ndarray:
    """Flat feature-patch index of every ``stride``-th pixel, row-major (read-only, cached)."""
    rows = np.arange(0, height, stride) * fh // height
    cols = np.arange(0, width, stride) * fw // width
    plane = (rows[:, None] * fw + cols[None, :]).reshape(-1)
    plane.flags.writeable = False
    return plane


def _patch_counts(
    run_cell: np.ndarray,
    run_patch: np.ndarray,
    lengths: np.ndarray,
    num_cells: int,
    num_patches: int,
) -> sparse.csr_matrix:
    """The sparse (cells x patches) matrix of pixel counts, from runs of equal (cell, patch).

    scipy's COO -> CSR conversion sums the runs of one (cell, patch) pair and sorts each
    row's patches (a counting sort by cell, then small per-row sorts): the same matrix as
    ``np.unique`` of the pair keys, about three times faster.
    """
    counts = sparse.csr_matrix(
        (lengths.astype(np.float32), (run_cell, run_patch)), shape=(num_cells, num_patches)
    )
    counts.sum_duplicates()
    return counts


def _as_float32(values: np.ndarray) -> np.ndarray:
    """A contiguous float32 copy (or the array itself); float16 (the store's features) is
    widened by torch, exactly and ten times faster than numpy's conversion."""
    if values.dtype == np.float16:
        import torch  # here: importing the maps' modules (a --help) should not cost torch's 2 s

        with warnings.catch_warnings():  # a read-only map (the store's) is only read here
            warnings.simplefilter("ignore", UserWarning)
            source = torch.from_numpy(np.ascontiguousarray(values))
        return source.to(torch.float32).numpy()
    return np.ascontiguousarray(values, dtype=np.float32)


def _mean_features(
    counts: sparse.csr_matrix, feature_map: np.ndarray, text: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Per-cell normalised mean of the pixels' patch features, from (cell, patch) pixel counts.

    The sums are one sparse (cells x patches) count matrix times the (patches, d) feature
    map, so the d-dimensional work grows with the pairs. With ``text`` (n, d) also the
    samples' dot products with the vocabulary; when the view has more samples than patches
    they come from per-patch dot products, ``t . normalise(sum_p c_p F_p) =
    sum_p c_p (t . F_p) / ||sum_p c_p F_p||``, so the (k, n) logits cost
    (patches x d x n), not (k x d x n).
    """
    num_cells, num_patches = counts.shape
    d = feature_map.shape[-1]
    flat = _as_float32(feature_map).reshape(num_patches, d)
    mean = counts @ flat
    norm = np.sqrt(np.einsum("ij,ij->i", mean, mean))[:, None]
    np.maximum(norm, 1e-12, out=norm)
    mean /= norm
    dots = None
    if text is not None:
        text32 = np.asarray(text, dtype=np.float32)
        if num_cells <= num_patches:
            dots = mean @ text32.T
        else:
            dots = counts @ (flat @ text32.T)
            dots /= norm
    return mean, dots


def view_samples(
    frame: Frame,
    feature_map: np.ndarray,
    *,
    cell_size: float,
    stride: int = 1,
    z_min: float = -np.inf,
    z_max: float = np.inf,
    sigma_z: float | None,
    text: np.ndarray | None = None,
) -> ViewSamples:
    """The (view, cell) samples of one view with its (fh, fw, d) feature map.

    Every valid depth pixel (every ``stride``-th) is back-projected, kept if its world
    height lies in ``[z_min, z_max]``, and assigned to its cell and feature patch. A pixel
    weighs ``exp(-depth^2 / (2 sigma_z^2))`` (``sigma_z=None``: 1; the grid's is
    ``GridConfig.sigma_z``). With ``text`` (n, d), the
    samples' dot products with the vocabulary come along (``ViewSamples.dots``). The top of
    a cell is its highest pixel, the first in row-major order among equals.

    The pixels are read once, by a compiled loop (:func:`care_maps.fuse.pixels.pixel_runs`), into runs
    of neighbours that share their cell and patch, several times fewer than pixels; the rest
    of the work is on runs.
    """
    fh, fw, dim = feature_map.shape
    runs = pixel_runs(
        frame.depth_m,
        frame.K,
        frame.cam_to_world,
        stride,
        cell_size,
        z_min,
        z_max,
        _patch_of_pixel(frame.height, frame.width, fh, fw, stride),
    )
    if runs.size == 0:
        return _empty(dim, None if text is None else len(text))
    lo_x, lo_y = runs.ix.min(), runs.iy.min()
    nx, ny = int(runs.ix.max() - lo_x) + 1, int(runs.iy.max() - lo_y) + 1
    run_local = runs.ix - lo_x  # (local cell) = (ix - lo_x) * ny + (iy - lo_y), in place
    run_local *= ny
    run_local += runs.iy
    run_local -= lo_y
    local, run_cell = _compact(run_local, nx * ny)
    k = local.size
    keys = pack_cells(lo_x + local // ny, lo_y + local % ny)  # sorted: local order is (ix, iy)
    lengths = runs.lengths
    num_pixels = np.bincount(run_cell, weights=lengths, minlength=k).astype(np.int64)
    if sigma_z is None:
        weight = num_pixels.astype(np.float32)
    else:
        w = np.square(runs.depth, dtype=np.float32)
        w *= np.float32(-0.5 / sigma_z**2)
        np.exp(w, out=w)
        run_w = run_sums(w, runs.starts, lengths)
        weight = np.bincount(run_cell, weights=run_w, minlength=k).astype(np.float32)
    top_z, top = cell_tops(run_cell, runs.top, runs.top_at, k)
    counts = _patch_counts(run_cell, runs.patch, lengths, k, fh * fw)
    feature, dots = _mean_features(counts, feature_map, text)
    rgb = frame.rgb[::stride, ::stride].reshape(-1, 3)
    return ViewSamples(
        keys=keys,
        weight=weight,
        feature=feature,
        num_pixels=num_pixels,
        top_z=top_z.astype(np.float32),
        top_rgb=rgb[runs.pixel[top]],
        dots=dots,
    )
