"""Rerun view of an instance map: the scene cloud, the instances and the views chosen for them.

Entities (all under ``world``, z up):

- ``world/scene/rgb``: the scene cloud in its colours;
- ``world/scene/instances``: the points of every mask in the instance's colour;
- ``world/instances/boxes``: axis-aligned boxes labelled with the top class, its
  probability and the measures (entropy H, stderr SE, pwKL D, views m);
- ``world/views/<view_id>``: each view chosen by some instance, as a camera frustum with
  its image inside;
- ``world/instances/view_links``: a line from each instance's centre to each of its chosen
  cameras, so which views serve which instance can be read off the 3D view.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import rerun as rr
import rerun.blueprint as rrb

from care.store import Store, read_table
from care.viz import log_camera, open_recording

__all__ = ["ENTITY_BOXES", "ENTITY_LINKS", "ENTITY_RGB", "ENTITY_SEGMENTS", "log_instances"]

ENTITY_RGB = "world/scene/rgb"
ENTITY_SEGMENTS = "world/scene/instances"
ENTITY_BOXES = "world/instances/boxes"
ENTITY_LINKS = "world/instances/view_links"
ENTITY_VIEWS = "world/views"


def _palette(n: int) -> np.ndarray:
    """(n, 3) uint8 distinct-ish colours (golden-ratio hues)."""
    import matplotlib.colors as mcolors

    hue = (np.arange(n) * 0.618033988749895) % 1.0
    hsv = np.stack([hue, np.full(n, 0.75), np.full(n, 0.95)], axis=1)
    return (mcolors.hsv_to_rgb(hsv) * 255).astype(np.uint8)


def _labels(table, vocabulary: list[str]) -> list[str]:  # table: pa.Table
    top = table.column("top_classes").to_pylist()
    prob = table.column("top_probs").to_pylist()
    cols = {k: table.column(k).to_numpy() for k in ("entropy", "stderr", "pwkl", "num_views")}
    out = []
    for i in range(table.num_rows):  # one label string per instance
        name = vocabulary[top[i][0]] if top[i] else "?"
        p = float(prob[i][0]) if prob[i] else 0.0
        out.append(
            f"{i}: {name} {p:.2f} | H {cols['entropy'][i]:.2f} SE {cols['stderr'][i]:.3f} "
            f"D {cols['pwkl'][i]:.2f} m {cols['num_views'][i]}"
        )
    return out


def log_instances(store_path: Path, rrd: Path, *, app_id: str = "care_instances") -> Path:
    """Write the instance map of the store at ``store_path`` to the Rerun file ``rrd``."""
    from fuse.instances import INSTANCE_VIEWS_TABLE, INSTANCES_TABLE, SCENE_POINTS_TABLE
    from fuse.pointcloud import read_scene_points

    store = Store(store_path)
    cloud = read_scene_points(store.table_path(SCENE_POINTS_TABLE))
    table = read_table(store.table_path(INSTANCES_TABLE))
    views = read_table(store.table_path(INSTANCE_VIEWS_TABLE), ["instance_id", "view_id", "rank"])
    vocabulary = json.loads((table.schema.metadata or {}).get(b"care.vocabulary", b"[]"))
    rec = open_recording(app_id, rrd)
    rec.send_blueprint(
        rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial3DView(origin="world", name="instances"),
                rrb.Spatial2DView(origin=ENTITY_VIEWS, name="chosen views"),
                column_shares=[3, 1],
            )
        )
    )
    rec.log(ENTITY_RGB, rr.Points3D(cloud.points, colors=cloud.colors), static=True)

    n = table.num_rows
    colours = _palette(max(n, 1))
    lengths = table.column("num_points").to_numpy()
    flat = pc.list_flatten(table.column("point_indices")).to_numpy()
    owner = np.repeat(np.arange(n), lengths)
    rec.log(ENTITY_SEGMENTS, rr.Points3D(cloud.points[flat], colors=colours[owner]), static=True)
    lo = np.asarray(table.column("bbox_min").to_pylist(), np.float32).reshape(-1, 3)
    hi = np.asarray(table.column("bbox_max").to_pylist(), np.float32).reshape(-1, 3)
    rec.log(
        ENTITY_BOXES,
        rr.Boxes3D(mins=lo, sizes=hi - lo, colors=colours[:n], labels=_labels(table, vocabulary)),
        static=True,
    )

    inst = views.column("instance_id").to_numpy()
    vid = views.column("view_id").to_numpy()
    chosen = np.unique(vid)
    meta = store.views(["view_id", "width", "height", "K", "cam_to_world", "rgb_jpeg"])
    keep = np.isin(meta.column("view_id").to_numpy(), chosen)
    meta = meta.filter(keep)
    poses = store.poses()[keep]  # in the map frame, like the cloud
    Ks = np.asarray(meta.column("K").to_pylist()).reshape(-1, 3, 3)
    ids = meta.column("view_id").to_numpy()
    for j, view_id in enumerate(ids):  # one camera per distinct chosen view
        entity = f"{ENTITY_VIEWS}/{int(view_id)}"
        w, h = meta.column("width")[j].as_py(), meta.column("height")[j].as_py()
        log_camera(rec, entity, poses[j], Ks[j], w, h)
        rec.log(
            f"{entity}/image",
            rr.EncodedImage(contents=meta.column("rgb_jpeg")[j].as_py(), media_type="image/jpeg"),
            static=True,
        )
    if len(inst):
        centres = np.asarray(table.column("center").to_pylist(), np.float32).reshape(-1, 3)
        cam_pos = poses[np.searchsorted(ids, vid), :3, 3]
        strips = np.stack([centres[inst], cam_pos], axis=1)
        rec.log(ENTITY_LINKS, rr.LineStrips3D(strips, colors=colours[inst]), static=True)
    rec.flush()
    return Path(rrd)
