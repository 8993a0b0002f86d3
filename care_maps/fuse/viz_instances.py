"""Rerun view of an instance map: the scene, the instances, and the views chosen for each.

Entities (all 3D ones under ``world``, z up):

- ``world/scene/rgb``: the scene cloud in its colours;
- ``world/instances/<i>``: instance ``i``'s box, labelled briefly (``3 nightstand``), so
  each can be selected and toggled; where boxes crowd, only the largest instance's label
  stays on screen (:func:`care_maps.geometry.labels.spread_labels`), the others show on hover; ``world/segments/<i>``: its points in its colour;
- on the ``instance`` timeline (one step per instance): ``world/selected`` highlights
  instance ``i`` and draws a line to each camera that sees it, ``world/chosen/<rank>`` holds
  its chosen views as cameras (pose, pinhole) with their JPEG inside, and ``instance`` a
  text document with its classes and measures (entropy H, stderr SE, pwKL D, views m).

The blueprint shows two 3D tabs (scene colours; instance colours: the two clouds are the
same points, so they never share a view), and beside them the selected instance's details
and its chosen views, each a 2D view rooted at the view's pinhole. The 3D views leave the
chosen cameras out (lines from the instance point at them): an instance with fewer views
clears the unused ranks, and the viewer reports a cleared pinhole's image in a 3D view.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import rerun as rr
import rerun.blueprint as rrb

from care_maps.core.keys import VOCABULARY_KEY
from care_maps.core.store import Store, read_table
from care_maps.core.viz import (
    log_camera,
    open_scene_recording,
    overview_eye,
    panels,
    send_blueprint,
)
from care_maps.geometry.labels import label_gap, spread_labels

__all__ = [
    "ENTITY_CHOSEN",
    "ENTITY_DETAILS",
    "ENTITY_INSTANCES",
    "ENTITY_RGB",
    "ENTITY_SEGMENTS",
    "ENTITY_SELECTED",
    "INSTANCE_TIMELINE",
    "instances_blueprint",
    "log_instances",
]

ENTITY_RGB = "world/scene/rgb"
ENTITY_SEGMENTS = "world/segments"
ENTITY_INSTANCES = "world/instances"
ENTITY_SELECTED = "world/selected"
ENTITY_CHOSEN = "world/chosen"
ENTITY_DETAILS = "instance"
INSTANCE_TIMELINE = "instance"
HIGHLIGHT = (255, 255, 255)


def _palette(n: int) -> np.ndarray:
    """(n, 3) uint8 distinct-ish colours (golden-ratio hues)."""
    import matplotlib.colors as mcolors

    hue = (np.arange(n) * 0.618033988749895) % 1.0
    hsv = np.stack([hue, np.full(n, 0.75), np.full(n, 0.95)], axis=1)
    return (mcolors.hsv_to_rgb(hsv) * 255).astype(np.uint8)


def _details(table: pa.Table, i: int, vocabulary: list[str], views: list[int]) -> str:
    """Markdown of instance ``i``: its top classes and measures, and its chosen views."""
    top = table.column("top_classes")[i].as_py() or []
    prob = table.column("top_probs")[i].as_py() or []
    row = {k: table.column(k)[i].as_py() for k in ("entropy", "stderr", "pwkl", "num_views")}
    classes = "\n".join(
        f"| {vocabulary[c]} | {p:.3f} |" for c, p in zip(top[:5], prob[:5], strict=True)
    )
    return (
        f"## Instance {i}: {vocabulary[top[0]] if top else '?'}\n\n"
        f"| entropy H | stderr SE | pwKL D | views m |\n|---|---|---|---|\n"
        f"| {row['entropy']:.3f} | {row['stderr']:.4f} | {row['pwkl']:.3g} | "
        f"{row['num_views']} |\n\n"
        f"Chosen views (best first): {', '.join(str(v) for v in views) or 'none'}\n\n"
        f"| class | probability |\n|---|---|\n{classes}\n"
    )


def instances_blueprint(max_views: int, eye: rrb.EyeControls3D | None = None) -> rrb.Blueprint:
    """The 3D tabs left; the selected instance's details and chosen views right."""
    scene = rrb.Spatial3DView(
        origin="world",
        contents=["+ world/**", f"- {ENTITY_SEGMENTS}/**", f"- {ENTITY_CHOSEN}/**"],
        name="3D: scene colours, boxes",
        eye_controls=eye,
    )
    segments = rrb.Spatial3DView(
        origin="world",
        contents=["+ world/**", f"- {ENTITY_RGB}", f"- {ENTITY_CHOSEN}/**"],
        name="3D: instance colours",
        eye_controls=eye,
    )
    chosen = [
        rrb.Spatial2DView(origin=f"{ENTITY_CHOSEN}/{r}", name=f"chosen view #{r + 1}")
        for r in range(max_views)
    ]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(scene, segments),
            rrb.Vertical(
                rrb.TextDocumentView(origin=ENTITY_DETAILS, name="selected instance"),
                rrb.Grid(*chosen, grid_columns=2) if chosen else rrb.Vertical(),
                row_shares=[2, 3],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(state="expanded", timeline=INSTANCE_TIMELINE, play_state="paused"),
        *panels()[:2],
    )


def log_instances(store_path: Path, rrd: Path, *, scene: str | None = None) -> Path:
    """Write the instance map of the store at ``store_path`` to the Rerun file ``rrd``."""
    from care_maps.fuse.instances import INSTANCE_VIEWS_TABLE, INSTANCES_TABLE, SCENE_POINTS_TABLE
    from care_maps.fuse.pointcloud import read_scene_points

    store = Store(store_path)
    cloud = read_scene_points(store.table_path(SCENE_POINTS_TABLE))
    table = read_table(store.table_path(INSTANCES_TABLE))
    views = read_table(store.table_path(INSTANCE_VIEWS_TABLE), ["instance_id", "view_id", "rank"])
    vocabulary = json.loads((table.schema.metadata or {}).get(VOCABULARY_KEY, b"[]"))
    rec = open_scene_recording(rrd, scene or Path(store_path).name)
    n = table.num_rows
    inst = views.column("instance_id").to_numpy()
    vid = views.column("view_id").to_numpy()
    rank = views.column("rank").to_numpy()
    max_views = int(np.bincount(inst).max()) if len(inst) else 0
    send_blueprint(rec, instances_blueprint(max_views, overview_eye(cloud.points)))
    rec.log(ENTITY_RGB, rr.Points3D(cloud.points, colors=cloud.colors), static=True)

    colours = _palette(max(n, 1))
    lengths = table.column("num_points").to_numpy()
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    flat = pc.list_flatten(table.column("point_indices")).to_numpy()
    lo = np.asarray(table.column("bbox_min").to_pylist(), np.float32).reshape(-1, 3)
    hi = np.asarray(table.column("bbox_max").to_pylist(), np.float32).reshape(-1, 3)
    top = table.column("top_classes").to_pylist()
    names = [vocabulary[t[0]] if t else "?" for t in top]
    # overlapping instances would pile their labels up: the largest of each neighbourhood
    # keeps its label on screen, the others show theirs on hover
    anchors = (lo + hi) / 2
    shown = spread_labels(anchors, lengths, label_gap(anchors))
    for i in range(n):  # one entity per instance: selectable, toggleable, its own label
        points = cloud.points[flat[offsets[i] : offsets[i + 1]]]
        rec.log(f"{ENTITY_SEGMENTS}/{i}", rr.Points3D(points, colors=colours[i]), static=True)
        rec.log(
            f"{ENTITY_INSTANCES}/{i}",
            rr.Boxes3D(
                mins=lo[i], sizes=hi[i] - lo[i], colors=colours[i], labels=f"{i} {names[i]}",
                show_labels=bool(shown[i]),
            ),
            static=True,
        )  # fmt: skip

    meta = store.views(["view_id", "width", "height", "K", "rgb_jpeg"])
    keep = pc.is_in(meta.column("view_id"), pa.array(np.unique(vid)))
    meta = meta.filter(keep)
    ids = meta.column("view_id").to_numpy()
    poses = store.poses()[keep.to_numpy(zero_copy_only=False)]  # the map frame, as the cloud
    Ks = np.asarray(meta.column("K").to_pylist()).reshape(-1, 3, 3)
    centres = np.asarray(table.column("center").to_pylist(), np.float32).reshape(-1, 3)
    for i in range(n):
        rec.set_time(INSTANCE_TIMELINE, sequence=i)
        mine = np.flatnonzero(inst == i)
        mine = mine[np.argsort(rank[mine], kind="stable")]
        rows = np.searchsorted(ids, vid[mine])
        rec.log(
            ENTITY_SELECTED,
            rr.Boxes3D(
                mins=lo[i], sizes=hi[i] - lo[i], colors=HIGHLIGHT, radii=0.02,
                labels=f"{i} {names[i]}",
            ),
        )  # fmt: skip
        links = [[centres[i], poses[j, :3, 3]] for j in rows]
        rec.log(f"{ENTITY_SELECTED}/views", rr.LineStrips3D(links, colors=HIGHLIGHT))
        for r in range(max_views):
            entity = f"{ENTITY_CHOSEN}/{r}"
            if r >= len(rows):
                rec.log(entity, rr.Clear(recursive=True))
                continue
            j = rows[r]
            w, h = meta.column("width")[j].as_py(), meta.column("height")[j].as_py()
            log_camera(rec, entity, poses[j], Ks[j], w, h)
            rec.log(
                f"{entity}/image",
                rr.EncodedImage(
                    contents=meta.column("rgb_jpeg")[j].as_py(), media_type="image/jpeg"
                ),
            )
        rec.log(
            ENTITY_DETAILS,
            rr.TextDocument(
                _details(table, i, vocabulary, [int(v) for v in vid[mine]]),
                media_type=rr.MediaType.MARKDOWN,
            ),
        )
    rec.flush()
    return Path(rrd)
