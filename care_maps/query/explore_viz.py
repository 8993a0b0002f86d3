"""Rerun logging of ``care explore``: the grid map, its uncertainty, the proposed views.

Entity paths (constants below): the grid as :func:`care_maps.fuse.viz_grid.log_grid` logs it (the
top-down layers under ``grid/``, the cells in the 3D ``world``), the cells' uncertainty as
one more top-down layer (``grid/uncertainty``, 0..1, values not colours, as every layer),
the viewpoints and their headings drawn over it, and in 3D each proposed camera (pose and
frustum, the recording's own intrinsics), its sight line to the target, the target and the
robot's goal pose on the floor. :func:`explore_blueprint` is the one layout: 3D left,
uncertainty and the map's layers in tabs right.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from care_maps.core.store import Store
from care_maps.core.viz import (
    log_camera,
    open_scene_recording,
    overview_eye,
    panels,
    send_blueprint,
)
from care_maps.fuse.grid import grid_image
from care_maps.fuse.measures import MEASURE_COLUMNS
from care_maps.fuse.viz_grid import LayerStyle, layer_entity, log_grid, log_layer
from care_maps.query.explore import cell_indices
from care_maps.query.explore_store import Exploration

__all__ = [
    "EXPLORE_ENTITY",
    "UNCERTAINTY_LAYER",
    "explore_blueprint",
    "log_exploration",
]

EXPLORE_ENTITY = "world/explore"
"""Parent of the proposed views in 3D: ``view_<rank>`` cameras, targets, sight lines, goals."""
UNCERTAINTY_LAYER = "uncertainty"
"""The top-down layer of each cell's uncertainty (``grid/uncertainty``)."""
_STYLE = LayerStyle("turbo", (0.0, 1.0))
_COLOUR = (255, 60, 200)
"""The proposed views' colour: apart from every colour map of the layers."""


def explore_blueprint(eye: rrb.EyeControls3D | None, title: str) -> rrb.Blueprint:
    """3D (map and views) on the left; the uncertainty layer, then the map's, in tabs."""
    layers = ["rgb", *MEASURE_COLUMNS[1:]]
    tabs = [rrb.Spatial2DView(origin=layer_entity(UNCERTAINTY_LAYER), name=title)]
    tabs += [rrb.Spatial2DView(origin=layer_entity(name), name=name) for name in layers]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="3D: map and proposed views", eye_controls=eye),
            rrb.Tabs(*tabs),
            column_shares=[3, 2],
        ),
        *panels(),
    )


def _log_top_down(rec: rr.RecordingStream, found: Exploration) -> str:
    """The uncertainty layer and the viewpoints over it; returns the tab's title."""
    layout, cmap = found.layout, found.cmap
    ix, iy = cell_indices(layout, cmap.positions[:, :2])
    lo, hi = log_layer(
        rec, UNCERTAINTY_LAYER, grid_image(ix, iy, found.uncertainty, layout.shape), _STYLE
    )
    if found.views:
        ny = layout.shape[1]
        ox, oy = layout.origin
        at = np.array(
            [[(x - ox) / layout.cell_size, ny - (y - oy) / layout.cell_size]
             for x, y in (v.position for v in found.views)]
        )  # fmt: skip
        heading = np.array([[math.cos(v.yaw), -math.sin(v.yaw)] for v in found.views])
        labels = [str(rank) for rank in range(1, len(found.views) + 1)]
        entity = f"{layer_entity(UNCERTAINTY_LAYER)}/views"
        rec.log(
            entity,
            rr.Arrows2D(
                origins=at,
                vectors=heading * (0.6 / layout.cell_size),
                colors=_COLOUR,
                labels=labels,
                radii=1.0,
                draw_order=2.0,
            ),
            static=True,
        )
    return f"uncertainty [{lo:.3g}, {hi:.3g}] {_STYLE.colormap}: proposed views"


def _log_views(rec: rr.RecordingStream, store: Path, found: Exploration) -> None:
    """Each proposed camera with its frustum, sight line, target and floor goal, in 3D."""
    views = Store(store).views(["width", "height", "K"]).slice(0, 1).to_pylist()
    if not views or not found.views:
        return
    width, height = int(views[0]["width"]), int(views[0]["height"])
    K = np.asarray(views[0]["K"], np.float64).reshape(3, 3)
    for rank, view in enumerate(found.views, 1):
        log_camera(rec, f"{EXPLORE_ENTITY}/view_{rank}", view.camera, K, width, height)
    eyes = np.array([v.camera[:3, 3] for v in found.views])
    targets = np.array([v.target for v in found.views])
    labels = [str(rank) for rank in range(1, len(found.views) + 1)]
    rec.log(
        f"{EXPLORE_ENTITY}/targets",
        rr.Points3D(targets, colors=_COLOUR, radii=0.06, labels=labels),
        static=True,
    )
    rec.log(
        f"{EXPLORE_ENTITY}/sight_lines",
        rr.LineStrips3D(np.stack([eyes, targets], axis=1), colors=_COLOUR, radii=0.01),
        static=True,
    )
    floor = np.array([[*v.position, 0.0] for v in found.views])
    heading = np.array([[0.5 * math.cos(v.yaw), 0.5 * math.sin(v.yaw), 0.0] for v in found.views])
    rec.log(
        f"{EXPLORE_ENTITY}/goals",
        rr.Arrows3D(origins=floor, vectors=heading, colors=_COLOUR, radii=0.03, labels=labels),
        static=True,
    )


def log_exploration(store: Path, found: Exploration, rrd: Path) -> None:
    """Write ``rrd``: the grid of ``store``, ``found``'s uncertainty and views, the blueprint."""
    rec = open_scene_recording(rrd, Path(store).name)
    log_grid(store, rec=rec)
    title = _log_top_down(rec, found)
    _log_views(rec, store, found)
    send_blueprint(rec, explore_blueprint(overview_eye(found.cmap.positions), title))
    rec.flush()
    rec.disconnect()
