"""One pass over a view's pixels: back-projection, the height band, cells and runs.

:func:`care_maps.fuse.cells.view_samples` needs, for every kept pixel of a view, its world height and
cell, and then the runs of neighbouring pixels that share a (cell, patch). As NumPy array
expressions that is about thirty passes over the 307k pixels of a 640x480 view, each
allocating and reading back a full-size temporary; as one compiled loop (numba) it is one
read of the depth image, with only the kept pixels and the runs written out.

The loop does every floating-point operation in the order the array expressions did (no
fused multiply-add, no fast-math reassociation: numba's defaults), so the heights, cells
and runs are the same bits, and so is the map. The weight's ``exp`` stays in NumPy (its
float32 ``exp`` is not libm's, so its bits would differ), as does the rest of the sample
arithmetic, which works on runs, several times fewer than pixels.

The kernels are built by :func:`care_maps.runtime.jit.kernel`: ``nogil`` (the grid's pipeline computes
a view's samples on a background thread while the main thread merges the previous view,
:func:`care_maps.fuse.grid._view_samples`) and cached on disk, compiled once per machine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from care_maps.runtime.jit import kernel

__all__ = ["PixelRuns", "cell_tops", "pixel_runs", "run_sums"]


@dataclass(frozen=True)
class PixelRuns:
    """A view's kept pixels (row-major) and their runs of equal (cell, patch).

    Attributes:
        pixel: (n,) int64 flat index of each kept pixel in the strided image.
        depth: (n,) its depth, in the depth image's float type (the store's: float32).
        starts: (m,) int64 first kept pixel of each run.
        lengths: (m,) int64 pixels in each run (all > 0).
        ix, iy: (m,) int64 each run's cell.
        patch: (m,) int64 each run's feature patch.
        top: (m,) float64 the run's greatest world height.
        top_at: (m,) int64 the first kept pixel of the run at that height.
    """

    pixel: np.ndarray
    depth: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    ix: np.ndarray
    iy: np.ndarray
    patch: np.ndarray
    top: np.ndarray
    top_at: np.ndarray

    @property
    def size(self) -> int:
        """Kept pixels."""
        return int(self.pixel.size)


@kernel
def _pixel_runs(depth, stride, xn, yn, R, t, cell_size, z_min, z_max, check_inf, patch_of_pixel):
    rows, cols = yn.size, xn.size
    limit = rows * cols
    pixel = np.empty(limit, np.int64)
    kept_depth = np.empty(limit, depth.dtype)
    starts = np.empty(limit, np.int64)
    run_ix = np.empty(limit, np.int64)
    run_iy = np.empty(limit, np.int64)
    run_patch = np.empty(limit, np.int64)
    top = np.empty(limit, np.float64)
    top_at = np.empty(limit, np.int64)
    # per row: the geometry of every pixel first, a branch-free loop the compiler turns
    # into vector instructions; then the band test and the runs, on those numbers
    row_depth = np.empty(cols, depth.dtype)
    row_height = np.empty(cols, np.float64)
    row_x = np.empty(cols, np.float64)  # floor(x / cell_size), integral; int64 in runs only
    row_y = np.empty(cols, np.float64)
    n = 0
    m = 0
    last_x = last_y = 0.0
    last_patch = np.int64(-1)
    for r in range(rows):
        # the row terms of the three world axes' ray planes: R[a, 1] * yn + R[a, 2]
        row0 = R[0, 1] * yn[r] + R[0, 2]
        row1 = R[1, 1] * yn[r] + R[1, 2]
        row2 = R[2, 1] * yn[r] + R[2, 2]
        for c in range(cols):
            row_depth[c] = depth[r * stride, c * stride]
        for c in range(cols):
            z = np.float64(row_depth[c])
            height = z * (R[2, 0] * xn[c] + row2)
            row_height[c] = height + t[2]
            x = (R[0, 0] * xn[c] + row0) * z
            row_x[c] = np.floor((x + t[0]) / cell_size)
            y = (R[1, 0] * xn[c] + row1) * z
            row_y[c] = np.floor((y + t[1]) / cell_size)
        for c in range(cols):
            z = np.float64(row_depth[c])
            height = row_height[c]
            # NaN depths and heights fail every comparison; an infinite depth gives an
            # infinite or NaN height, which only an infinite bound lets through
            if not (height >= z_min and height <= z_max and z > 0):
                continue
            if check_inf and not z < np.inf:
                continue
            x = row_x[c]
            y = row_y[c]
            flat = r * cols + c
            p = patch_of_pixel[flat]
            if m == 0 or x != last_x or y != last_y or p != last_patch:
                starts[m] = n
                run_ix[m] = np.int64(x)
                run_iy[m] = np.int64(y)
                last_x, last_y, last_patch = x, y, p
                run_patch[m] = p
                top[m] = height
                top_at[m] = n
                m += 1
            elif height > top[m - 1]:  # strictly: the first pixel at the top stays
                top[m - 1] = height
                top_at[m - 1] = n
            pixel[n] = flat
            kept_depth[n] = row_depth[c]
            n += 1
    return (
        pixel[:n].copy(),
        kept_depth[:n].copy(),
        starts[:m].copy(),
        run_ix[:m].copy(),
        run_iy[:m].copy(),
        run_patch[:m].copy(),
        top[:m].copy(),
        top_at[:m].copy(),
    )


def pixel_runs(
    depth_m: np.ndarray,
    K: np.ndarray,
    cam_to_world: np.ndarray,
    stride: int,
    cell_size: float,
    z_min: float,
    z_max: float,
    patch_of_pixel: np.ndarray,
) -> PixelRuns:
    """Every ``stride``-th pixel of ``depth_m`` with a positive, finite depth whose world
    height lies in ``[z_min, z_max]``, its cell ``floor((x, y) / cell_size)`` and feature
    patch (``patch_of_pixel``, flat over the strided image), grouped into runs of equal
    (cell, patch) in row-major order.

    A pixel's world point is ``z * R (xn, yn, 1) + t`` with the normalised image coordinates
    ``xn`` of its column and ``yn`` of its row, each axis evaluated as
    ``z * ((R[a, 0] xn) + (R[a, 1] yn + R[a, 2])) + t[a]``.
    """
    xn = (np.arange(0, depth_m.shape[1], stride) - K[0, 2]) / K[0, 0]
    yn = (np.arange(0, depth_m.shape[0], stride) - K[1, 2]) / K[1, 1]
    R = np.ascontiguousarray(cam_to_world[:3, :3], dtype=np.float64)
    t = np.ascontiguousarray(cam_to_world[:3, 3], dtype=np.float64)
    depth = np.asarray(depth_m)
    if depth.dtype not in (np.float32, np.float64):  # the store's is float32; integer depth
        depth = depth.astype(np.float64)  # or another byte order: exactly, as the loop reads it
    check_inf = not (np.isfinite(z_min) and np.isfinite(z_max))
    pixel, depth, starts, ix, iy, patch, top, top_at = _pixel_runs(
        depth,
        int(stride),
        xn,
        yn,
        R,
        t,
        float(cell_size),
        float(z_min),
        float(z_max),
        check_inf,
        _read_only(patch_of_pixel),
    )
    lengths = np.diff(starts, append=pixel.size)
    return PixelRuns(pixel, depth, starts, lengths, ix, iy, patch, top, top_at)


def _read_only(values: np.ndarray) -> np.ndarray:
    """A read-only int64 view (or copy) of ``values``: the patch plane comes read-only from
    its cache, and one array type means one compiled signature (each new one compiles for
    seconds, once per machine)."""
    out = np.ascontiguousarray(values, np.int64)
    if out.flags.writeable:
        out = out.view()
        out.flags.writeable = False
    return out


@kernel
def _run_sums(values, starts, lengths):
    out = np.empty(starts.size, np.float64)
    for i in range(starts.size):
        acc = 0.0
        for j in range(starts[i], starts[i] + lengths[i]):
            acc += np.float64(values[j])
        out[i] = acc
    return out


def run_sums(values: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(m,) float64 sum of each run of ``values``, left to right from 0 (the order of
    ``np.add.reduceat``, so the same bits)."""
    return _run_sums(values, starts, lengths)


@kernel
def _cell_tops(run_cell, top, top_at, num_cells):
    top_z = np.full(num_cells, -np.inf)
    first = np.zeros(num_cells, np.int64)
    for i in range(run_cell.size):
        cell = run_cell[i]
        if top[i] > top_z[cell]:  # strictly: runs come in pixel order, the first one stays
            top_z[cell] = top[i]
            first[cell] = top_at[i]
    return top_z, first


def cell_tops(
    run_cell: np.ndarray, top: np.ndarray, top_at: np.ndarray, num_cells: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per cell (``run_cell`` numbers the runs' cells 0..num_cells-1): its greatest height
    and the first pixel, in row-major order, that reaches it."""
    return _cell_tops(run_cell, top, top_at, num_cells)


def warm_up() -> None:
    """Load (or compile) the kernels for the types a fusion passes them.

    A process's first call of a numba function loads numba's CPU target (about half a
    second, in Python) and the cached machine code. :func:`care_maps.fuse.grid.build_grid` calls this
    on a background thread while it samples the store for the height-band check, so that
    time overlaps the check's PNG decoding instead of stalling the first view.
    """
    from care_maps.fuse.welford import merge_moments

    plane = np.zeros(4, np.int64)
    plane.flags.writeable = False  # as the patch-plane cache hands it out
    runs = pixel_runs(np.ones((2, 2), np.float32), np.eye(3), np.eye(4), 1, 1.0, -2.0, 2.0, plane)
    run_sums(np.ones(runs.size, np.float32), runs.starts, runs.lengths)
    cell_tops(np.zeros(runs.starts.size, np.int64), runs.top, runs.top_at, 1)
    merge_moments(
        np.zeros((1, 2), np.float32),
        np.zeros(1, np.int64),
        np.ones((1, 1), np.float32),
        np.ones(1, bool),
        np.ones(1, np.float32),
        np.ones(1, np.float32),
    )
