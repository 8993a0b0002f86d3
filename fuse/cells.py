"""Top-down cells: integer grid keys, a growing key -> compact id index, and per-view samples.

A cell is ``(ix, iy) = floor((x, y) / cell_size)`` in world metres, so the grid's extent
comes from the data and only occupied cells ever get an id. Ids are handed out in order of
first appearance as views stream in, so they are stable during a pass and equal the final
``candidate_id``.

:func:`view_samples` turns one view into its (view, cell) samples. Pixels that share a cell
and a feature patch are collapsed into one counted term first (``np.unique`` on
``(cell, patch)`` keys), so the d-dimensional work grows with (cell, patch) pairs, not
pixels x d.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from care.frames import Frame
from care.geometry import backproject

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
        feature: (k, d) float32 mean pixel feature, L2-normalised (``cell_views.parquet``
            keeps it as float16).
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


def _compact(values: np.ndarray, bound: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(values, return_inverse=True, return_counts=True)`` for ints in [0, bound).

    A bincount over the bound when it is small next to the data (O(N), no sort), the sort of
    ``np.unique`` otherwise.
    """
    if bound <= max(4 * values.size, 1 << 16):
        counts = np.bincount(values, minlength=bound)
        uniq = np.flatnonzero(counts)
        remap = np.zeros(bound, np.int64)
        remap[uniq] = np.arange(uniq.size)
        return uniq, remap[values], counts[uniq]
    return np.unique(values, return_inverse=True, return_counts=True)


def _mean_features(
    cell_of: np.ndarray,
    patch: np.ndarray,
    num_cells: int,
    feature_map: np.ndarray,
    text: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Per-cell normalised mean of the pixels' patch features, via one term per (cell, patch).

    With ``text`` (n, d) also the samples' dot products with the vocabulary. When the view
    has more samples than patches they come from per-patch dot products,
    ``t . normalise(sum_p c_p F_p) = sum_p c_p (t . F_p) / ||sum_p c_p F_p||``, so the (k, n)
    logits cost (patches x d x n), not (k x d x n).
    """
    fh, fw, d = feature_map.shape
    num_patches = fh * fw
    pairs, _, count = _compact(cell_of * num_patches + patch, num_cells * num_patches)
    pair_cell = torch.from_numpy(pairs // num_patches)
    pair_patch = torch.from_numpy(pairs % num_patches)
    weight = torch.from_numpy(count.astype(np.float32))[:, None]
    flat = torch.from_numpy(np.ascontiguousarray(feature_map, dtype=np.float32).reshape(-1, d))
    sums = torch.zeros(num_cells, d, dtype=torch.float32).index_add_(
        0, pair_cell, flat[pair_patch] * weight
    )
    norm = torch.linalg.vector_norm(sums, dim=1, keepdim=True).clamp_min(1e-12)
    mean = sums / norm
    dots = None
    if text is not None:
        text_t = torch.from_numpy(np.asarray(text, dtype=np.float32))
        used, pair_used = torch.unique(pair_patch, return_inverse=True)
        if num_cells <= used.numel():  # fewer samples than patches: multiply directly
            dots = (mean @ text_t.T).numpy()
        else:
            patch_dots = flat[used] @ text_t.T
            raw = torch.zeros(num_cells, patch_dots.shape[1], dtype=torch.float32)
            dots = (raw.index_add_(0, pair_cell, patch_dots[pair_used] * weight) / norm).numpy()
    return mean.numpy(), dots


def view_samples(
    frame: Frame,
    feature_map: np.ndarray,
    *,
    cell_size: float,
    stride: int = 1,
    z_min: float = -np.inf,
    z_max: float = np.inf,
    sigma_z: float | None = 2.5,
    text: np.ndarray | None = None,
) -> ViewSamples:
    """The (view, cell) samples of one view with its (fh, fw, d) feature map.

    (The camera-to-world transform is written out per coordinate: only the height is needed
    before the band filter, and (N, 3) @ (3, 3) is slow in numpy.)

    Every valid depth pixel (every ``stride``-th) is back-projected, kept if its world
    height lies in ``[z_min, z_max]``, and assigned to its cell and feature patch. A pixel
    weighs ``exp(-depth^2 / (2 sigma_z^2))`` (``sigma_z=None``: 1). With ``text`` (n, d), the
    samples' dot products with the vocabulary come along (``ViewSamples.dots``).
    """
    fh, fw, dim = feature_map.shape
    points, pixels = backproject(frame.depth_m, frame.K, stride)
    R, t = frame.cam_to_world[:3, :3], frame.cam_to_world[:3, 3]
    x, y, depth = points[:, 0], points[:, 1], points[:, 2]
    height = R[2, 0] * x + R[2, 1] * y + R[2, 2] * depth + t[2]
    keep = (height >= z_min) & (height <= z_max)
    if not keep.any():
        return _empty(dim, None if text is None else len(text))
    x, y, depth, height, pixels = x[keep], y[keep], depth[keep], height[keep], pixels[keep]
    ix = np.floor((R[0, 0] * x + R[0, 1] * y + R[0, 2] * depth + t[0]) / cell_size).astype(np.int64)
    iy = np.floor((R[1, 0] * x + R[1, 1] * y + R[1, 2] * depth + t[1]) / cell_size).astype(np.int64)
    lo_x, lo_y = ix.min(), iy.min()
    ny = int(iy.max() - lo_y) + 1
    local, cell_of, num_pixels = _compact(
        (ix - lo_x) * ny + (iy - lo_y), (int(ix.max() - lo_x) + 1) * ny
    )
    keys = pack_cells(lo_x + local // ny, lo_y + local % ny)  # sorted: local order is (ix, iy)
    u, v = pixels[:, 0], pixels[:, 1]
    patch = (v * fh // frame.height) * fw + u * fw // frame.width
    feature, dots = _mean_features(cell_of, patch, keys.size, feature_map, text)
    w = np.ones_like(depth) if sigma_z is None else np.exp(-(depth**2) / (2.0 * sigma_z**2))
    weight = np.bincount(cell_of, weights=w, minlength=keys.size).astype(np.float32)
    # highest pixel per cell: a scatter-max, then any pixel reaching it
    top_z = torch.full((keys.size,), -torch.inf, dtype=torch.float64)
    top_z = top_z.scatter_reduce_(
        0, torch.from_numpy(cell_of), torch.from_numpy(height), "amax"
    ).numpy()
    at_top = np.flatnonzero(height == top_z[cell_of])
    top = np.empty(keys.size, np.int64)
    top[cell_of[at_top]] = at_top
    return ViewSamples(
        keys=keys,
        weight=weight,
        feature=feature,
        num_pixels=num_pixels,
        top_z=top_z.astype(np.float32),
        top_rgb=frame.rgb[v[top], u[top]],
        dots=dots,
    )
