"""Rerun logging of the grid map: one real-valued image layer per measure, and a blueprint.

Entity paths (constants below): the top-down layers live under ``grid/`` as 2D images (row 0
= north, as :func:`care_maps.fuse.grid.grid_image` lays them out); the cells also appear in the 3D
``world`` as points at their highest fused point, coloured by RGB. :func:`map_blueprint` is
the one layout of the map recording (3D view left, top-down tabs right).

Values, not colours: each measure is logged as a float32 ``DepthImage`` (``meter=1``, so the
viewer's hover shows the cell's value) with a colour map and an explicit value range, which
the tab's title spells out. Cells no view observed, and cells whose pwKL is +inf (a class
seen by a single view has no spread), are NaN in the value image and drawn by a
``<layer>/status`` segmentation overlay in their own labelled colours, so neither is
confused with a small or a large value.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from care_maps.core.errors import FuseError
from care_maps.core.keys import LOGIT_SCALE_KEY, VOCABULARY_KEY
from care_maps.core.store import Store, read_table
from care_maps.core.viz import open_scene_recording, overview_eye, panels, send_blueprint
from care_maps.core.vocab import STRUCTURE_NAMES
from care_maps.fuse.grid import CELLS_TABLE, GridLayout, grid_image
from care_maps.fuse.measures import MEASURE_COLUMNS
from care_maps.fuse.vocabulary import vocabulary_text

__all__ = [
    "GRID_CELLS_3D",
    "GRID_ENTITY",
    "MEASURE_LAYERS",
    "LayerStyle",
    "confidence_layer",
    "confidence_raster",
    "default_class",
    "layer_entity",
    "log_grid",
    "log_layer",
    "map_blueprint",
    "measure_layers",
]

GRID_ENTITY = "grid"
"""Parent of the top-down image layers: ``grid/rgb``, ``grid/entropy``, ..."""
GRID_CELLS_3D = "world/grid/cells"
"""The occupied cells as 3D points at (x, y, z_max), coloured by RGB."""
MEASURE_LAYERS = MEASURE_COLUMNS
"""Measure layers in tab order; ``confidence`` is for the class chosen at logging time."""
STATUS_OBSERVED, STATUS_UNOBSERVED, STATUS_INFINITE = 0, 1, 2
"""Classes of a layer's ``status`` overlay."""
_STATUS_CONTEXT = rr.AnnotationContext(
    [
        (STATUS_OBSERVED, "value", (0, 0, 0, 0)),
        (STATUS_UNOBSERVED, "not observed", (128, 128, 128, 255)),
        (STATUS_INFINITE, "+inf", (0, 220, 255, 255)),
    ]
)


@dataclass(frozen=True)
class LayerStyle:
    """Colour map and how its range is chosen for one measure."""

    colormap: rr.components.ColormapLike
    fixed: tuple[float, float] | None = None
    """A fixed range (a probability is 0..1); None: the 1st..99th percentile of the finite
    values, so one outlier cell does not wash out the layer."""


STYLES = {
    "confidence": LayerStyle("viridis", (0.0, 1.0)),
    "entropy": LayerStyle("magma"),
    "stderr": LayerStyle("plasma"),
    "pwkl": LayerStyle("inferno"),
    "num_views": LayerStyle("cyantoyellow"),
}


def confidence_layer(name: str) -> str:
    """Layer name of the confidence of class ``name`` (spaces kept out of entity paths)."""
    return f"confidence_{name.replace(' ', '_')}"


def layer_entity(layer: str) -> str:
    """Entity path of a top-down layer."""
    return f"{GRID_ENTITY}/{layer}"


def default_class(cells: pa.Table) -> str | None:
    """The object class (not wall, floor, ...) that most cells have as their top class."""
    vocabulary = json.loads((cells.schema.metadata or {}).get(VOCABULARY_KEY, b"[]"))
    top = [c[0] for c in cells.column("top_classes").to_pylist() if c]
    counts = Counter(vocabulary[i] for i in top if vocabulary[i].lower() not in STRUCTURE_NAMES)
    if counts:
        return counts.most_common(1)[0][0]
    return next((v for v in vocabulary if v.lower() not in STRUCTURE_NAMES), None)


def _value_range(values: np.ndarray, style: LayerStyle) -> tuple[float, float]:
    if style.fixed is not None:
        return style.fixed
    finite = values[np.isfinite(values)]
    if not finite.size:
        return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(finite, [1, 99]))
    return (lo, hi) if hi > lo else (lo, lo + 1.0)


def log_layer(
    rec: rr.RecordingStream,
    layer: str,
    raster: np.ndarray,
    style: LayerStyle,
    *,
    static: bool = True,
) -> tuple[float, float]:
    """Log one measure raster (NaN = unobserved) at ``grid/<layer>``; returns its range."""
    raster = np.asarray(raster, np.float64)
    status = np.where(np.isnan(raster), STATUS_UNOBSERVED, STATUS_OBSERVED)
    status[np.isposinf(raster)] = STATUS_INFINITE
    values = np.where(np.isfinite(raster), raster, np.nan).astype(np.float32)
    lo, hi = _value_range(values, style)
    entity = layer_entity(layer)
    rec.log(
        f"{entity}/value",
        rr.DepthImage(
            values, meter=1.0, colormap=style.colormap, depth_range=[lo, hi], draw_order=0.0
        ),
        static=static,
    )
    rec.log(
        f"{entity}/status",
        rr.SegmentationImage(status.astype(np.uint8), opacity=1.0, draw_order=1.0),
        static=static,
    )
    return lo, hi


def confidence_raster(store: Store, cells: pa.Table, target: str) -> np.ndarray:
    """Raster (ny, nx) of P_c[target], exact for any class the store can embed:
    ``exp(s f . t - log_norm)`` from the stored fused feature, not the truncated
    ``top_probs``."""
    md = cells.schema.metadata or {}
    layout = GridLayout.from_table(cells)
    ix, iy = cells.column("ix").to_numpy(), cells.column("iy").to_numpy()
    _, text = vocabulary_text(store, [target])
    feature = cells.column("feature").combine_chunks()
    flat = feature.values.to_numpy(zero_copy_only=False).astype(np.float64)
    scale = float(md.get(LOGIT_SCALE_KEY, b"100"))
    logits = scale * flat.reshape(len(feature), -1) @ text[0].astype(np.float64)
    conf = np.exp(logits - cells.column("log_norm").to_numpy())
    return grid_image(ix, iy, conf, layout.shape)


def measure_layers(
    store: Store, cells: pa.Table, target: str | None = None
) -> dict[str, np.ndarray]:
    """Rasters (ny, nx) of each measure; ``confidence`` is P_c[target] (default:
    :func:`default_class`; see :func:`confidence_raster`)."""
    layout = GridLayout.from_table(cells)
    ix, iy = cells.column("ix").to_numpy(), cells.column("iy").to_numpy()
    target = target if target is not None else default_class(cells)
    layers: dict[str, np.ndarray] = {}
    if target is not None:
        layers["confidence"] = confidence_raster(store, cells, target)
    for name in MEASURE_LAYERS[1:]:
        values = cells.column(name).to_numpy().astype(np.float64)
        layers[name] = grid_image(ix, iy, values, layout.shape)
    return layers


def _tab_title(layer: str, lo: float, hi: float, colormap: rr.components.ColormapLike) -> str:
    return f"{layer} [{lo:.3g}, {hi:.3g}] {colormap}"


def map_blueprint(
    *,
    views_3d: Sequence[rrb.View] = (),
    layers: Sequence[str] = ("rgb", *MEASURE_LAYERS),
    titles: dict[str, str] | None = None,
    eye: rrb.EyeControls3D | None = None,
    grouped: Sequence[str] = (),
) -> rrb.Blueprint:
    """The map recording's layout: 3D views on the left, one top-down tab per layer right.

    ``grouped`` layers (the confidence of several classes) share one tab of their own tabs.
    """
    titles = titles or {}

    def view(name: str) -> rrb.View:
        return rrb.Spatial2DView(origin=layer_entity(name), name=titles.get(name, name))

    tabs: list[rrb.View | rrb.Container] = []
    for name in layers:
        if name in grouped:
            if name == grouped[0]:
                tabs.append(rrb.Tabs(*map(view, grouped), name="confidence of query classes"))
        else:
            tabs.append(view(name))
    left = [
        rrb.Spatial3DView(
            origin="world", name="3D: cells at their highest point", eye_controls=eye
        ),
        *views_3d,
    ]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(*left) if len(left) > 1 else left[0],
            rrb.Tabs(*tabs),
            column_shares=[3, 2],
        ),
        *panels(),
    )


def log_grid(
    store_path: Path,
    rrd: Path | None = None,
    *,
    target: str | Sequence[str] | None = None,
    rec: rr.RecordingStream | None = None,
    scene: str | None = None,
) -> rr.RecordingStream:
    """Log the grid of ``store_path`` to ``rec`` (or a new recording saved to ``rrd``).

    ``target``: the class of the confidence layer (default :func:`default_class`), named in
    its entity path (``grid/confidence_<class>``) and tab; several classes (e.g. the
    evaluation's query classes) give a layer each, under one tab of tabs. ``scene`` names the
    recording (default the store's directory name). Sends :func:`map_blueprint` when it opens
    the recording itself.
    """
    store = Store(store_path)
    cells = read_table(store.table_path(CELLS_TABLE))
    own = rec is None
    if rec is None:
        if rrd is None:
            msg = "log_grid needs an rrd path or an open recording"
            raise FuseError(msg)
        rec = open_scene_recording(rrd, scene or Path(store_path).name)
    if target is None:
        targets = [c for c in [default_class(cells)] if c is not None]
    else:
        targets = [target] if isinstance(target, str) else list(dict.fromkeys(target))
    if targets:
        vocabulary_text(store, targets)  # an unknown class fails here, before any logging
    layout = GridLayout.from_table(cells)
    ix, iy = cells.column("ix").to_numpy(), cells.column("iy").to_numpy()
    rgb = np.stack([cells.column(c).to_numpy() for c in "rgb"], axis=1)
    rec.log(GRID_ENTITY, _STATUS_CONTEXT, static=True)
    rec.log(
        f"{layer_entity('rgb')}/value",
        rr.Image(grid_image(ix, iy, rgb, layout.shape, fill=0).astype(np.uint8), draw_order=0.0),
        static=True,
    )
    observed = grid_image(ix, iy, np.ones(len(ix)), layout.shape)
    rec.log(
        f"{layer_entity('rgb')}/status",
        rr.SegmentationImage(
            np.where(np.isnan(observed), STATUS_UNOBSERVED, STATUS_OBSERVED).astype(np.uint8),
            opacity=1.0,
            draw_order=1.0,
        ),
        static=True,
    )
    titles, layers = {"rgb": "rgb"}, ["rgb"]
    for name in targets:
        layer, style = confidence_layer(name), STYLES["confidence"]
        lo, hi = log_layer(rec, layer, confidence_raster(store, cells, name), style)
        titles[layer] = _tab_title(f"P({name})", lo, hi, style.colormap)
        layers.append(layer)
    for name, raster in measure_layers(store, cells, targets[0] if targets else None).items():
        if name == "confidence":
            continue
        style = STYLES[name]
        lo, hi = log_layer(rec, name, raster, style)
        titles[name] = _tab_title(name, lo, hi, style.colormap)
        layers.append(name)
    xyz = np.stack(
        [
            cells.column("x").to_numpy(),
            cells.column("y").to_numpy(),
            cells.column("z_max").to_numpy(),
        ],
        axis=1,
    )
    if own:
        grouped = layers[1 : 1 + len(targets)] if len(targets) > 1 else []
        send_blueprint(
            rec, map_blueprint(layers=layers, titles=titles, eye=overview_eye(xyz), grouped=grouped)
        )
    rec.log(GRID_CELLS_3D, rr.Points3D(xyz, colors=rgb, radii=layout.cell_size / 2), static=True)
    if own:
        rec.flush()
    return rec
