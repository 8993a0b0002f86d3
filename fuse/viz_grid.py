"""Rerun logging of the grid map: one colour-mapped image layer per measure, and a blueprint.

Entity paths (constants below): the top-down layers live under ``grid/`` as 2D images (row 0
= north, as :func:`fuse.grid.grid_image` lays them out); the cells also appear in the 3D
``world`` as points at their highest fused point, coloured by RGB. :func:`map_blueprint` is
the one layout of the map recording (3D view left, top-down tabs right); the instance map
adds its own 3D views through its ``views_3d`` argument.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb
from matplotlib import colormaps

from care.errors import FuseError
from care.store import Store, read_table
from care.viz import open_recording
from fuse.grid import CELLS_TABLE, GridLayout, grid_image
from fuse.vocabulary import vocabulary_text

__all__ = [
    "GRID_CELLS_3D",
    "GRID_ENTITY",
    "MEASURE_LAYERS",
    "colourise",
    "log_grid",
    "map_blueprint",
    "measure_layers",
]

GRID_ENTITY = "grid"
"""Parent of the top-down image layers: ``grid/rgb``, ``grid/entropy``, ..."""
GRID_CELLS_3D = "world/grid/cells"
"""The occupied cells as 3D points at (x, y, z_max), coloured by RGB."""
MEASURE_LAYERS = ("confidence", "entropy", "stderr", "pwkl", "num_views")
"""Measure layers in tab order; ``confidence`` is for the class chosen at logging time."""


def colourise(values: np.ndarray, cmap: str = "viridis") -> np.ndarray:
    """(H, W, 4) uint8 RGBA of a float raster; NaN (no cell) transparent, +inf the top colour.

    Ranges are robust (1st..99th percentile of the finite values) so one outlier cell
    does not wash out the layer.
    """
    values = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    lo, hi = np.percentile(values[finite], [1, 99]) if finite.any() else (0.0, 1.0)
    span = hi - lo if hi > lo else 1.0
    scaled = np.clip((np.where(finite, values, hi) - lo) / span, 0.0, 1.0)
    rgba = (colormaps[cmap](scaled) * 255).astype(np.uint8)
    rgba[np.isnan(values)] = 0
    return rgba


def measure_layers(
    store: Store, cells: pa.Table, target: str | None = None
) -> dict[str, np.ndarray]:
    """Rasters (ny, nx) of each measure; ``confidence`` is P_c[target] (default: first class).

    The confidence is exact for any class the store can embed: ``exp(s f . t - log_norm)``
    from the stored fused feature, not the truncated ``top_probs``.
    """
    md = cells.schema.metadata or {}
    layout = GridLayout.from_table(cells)
    ix, iy = cells.column("ix").to_numpy(), cells.column("iy").to_numpy()
    vocabulary = json.loads(md.get(b"care.vocabulary", b"[]"))
    target = target if target is not None else (vocabulary[0] if vocabulary else None)
    layers: dict[str, np.ndarray] = {}
    if target is not None:
        _, text = vocabulary_text(store, [target])
        feature = cells.column("feature").combine_chunks()
        flat = feature.values.to_numpy(zero_copy_only=False).astype(np.float64)
        scale = float(md.get(b"care.logit_scale", b"100"))
        logits = scale * flat.reshape(len(feature), -1) @ text[0].astype(np.float64)
        conf = np.exp(logits - cells.column("log_norm").to_numpy())
        layers["confidence"] = grid_image(ix, iy, conf, layout.shape)
    for name in MEASURE_LAYERS[1:]:
        values = cells.column(name).to_numpy().astype(np.float64)
        layers[name] = grid_image(ix, iy, values, layout.shape)
    return layers


def map_blueprint(
    *, views_3d: Sequence[rrb.View] = (), layers: Sequence[str] = ("rgb", *MEASURE_LAYERS)
) -> rrb.Blueprint:
    """The map recording's layout: 3D views on the left, one top-down tab per layer right."""
    tabs = [rrb.Spatial2DView(origin=f"{GRID_ENTITY}/{name}", name=name) for name in layers]
    left = [rrb.Spatial3DView(origin="world", name="3D"), *views_3d]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(*left) if len(left) > 1 else left[0],
            rrb.Tabs(*tabs),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def log_grid(
    store_path: Path,
    rrd: Path | None = None,
    *,
    target: str | None = None,
    rec: rr.RecordingStream | None = None,
) -> rr.RecordingStream:
    """Log the grid of ``store_path`` to ``rec`` (or a new recording saved to ``rrd``).

    Sends :func:`map_blueprint` when it opens the recording itself; a caller that passes
    ``rec`` sends its own blueprint (with its own 3D views).
    """
    store = Store(store_path)
    cells = read_table(store.table_path(CELLS_TABLE))
    own = rec is None
    if rec is None:
        if rrd is None:
            msg = "log_grid needs an rrd path or an open recording"
            raise FuseError(msg)
        rec = open_recording("care_map", rrd)
        rec.send_blueprint(map_blueprint())
    layout = GridLayout.from_table(cells)
    ix, iy = cells.column("ix").to_numpy(), cells.column("iy").to_numpy()
    rgb = np.stack([cells.column(c).to_numpy() for c in "rgb"], axis=1)
    rec.log(
        f"{GRID_ENTITY}/rgb",
        rr.Image(grid_image(ix, iy, rgb, layout.shape, fill=0).astype(np.uint8)),
        static=True,
    )
    cmaps = {"entropy": "magma", "stderr": "plasma", "pwkl": "inferno", "num_views": "cividis"}
    for name, raster in measure_layers(store, cells, target).items():
        rec.log(
            f"{GRID_ENTITY}/{name}",
            rr.Image(colourise(raster, cmaps.get(name, "viridis"))),
            static=True,
        )
    xyz = np.stack(
        [
            cells.column("x").to_numpy(),
            cells.column("y").to_numpy(),
            cells.column("z_max").to_numpy(),
        ],
        axis=1,
    )
    rec.log(GRID_CELLS_3D, rr.Points3D(xyz, colors=rgb, radii=layout.cell_size / 2), static=True)
    if own:
        rec.flush()
    return rec
