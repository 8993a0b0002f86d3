"""Rerun logging of sample scenes: meshes coloured by class, ground-truth boxes, trajectories.

Entity paths (``<scene>`` = ``scene_000``, ...)::

    world/<scene>/mesh          Mesh3D, vertex colours by class
    world/<scene>/instances     Boxes3D of every instance, labelled with its class
    world/<scene>/trajectory    LineStrips3D of the camera path
    world/<scene>/camera        the camera on the ``stamp`` timeline

Scenes of a dataset are laid side by side along x (each shifted past the previous one by
3 m) so the whole dataset can be looked at at once.
"""

from __future__ import annotations

import colorsys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import rerun as rr

from care_maps.core.outputs import write_atomic
from care_maps.core.viz import log_camera, open_recording, set_stamp
from care_maps.world.render import RenderConfig, intrinsics
from care_maps.world.scene import Scene, SceneConfig, generate_scene
from care_maps.world.trajectory import plan_trajectory

__all__ = ["class_colours", "log_dataset", "log_scene"]

APP_ID = "care_sample_world"
SCENE_GAP = 3.0


def class_colours(n: int) -> np.ndarray:
    """(n, 3) uint8 distinct colours; class 0 (void) black, structure classes greys."""
    golden = 0.618033988749895
    cols = [colorsys.hsv_to_rgb((i * golden) % 1.0, 0.65, 0.9) for i in range(n)]
    out = (np.asarray(cols) * 255).astype(np.uint8)
    out[0] = 0
    out[1:4] = [[200, 200, 200], [150, 130, 110], [235, 235, 235]][: max(0, min(3, n - 1))]
    return out


def log_scene(
    rec: rr.RecordingStream,
    name: str,
    scene: Scene,
    poses: np.ndarray,
    offset: np.ndarray,
    render: RenderConfig,
) -> None:
    """Log one scene under ``world/<name>``, shifted by ``offset``."""
    mesh = scene.mesh
    colours = class_colours(len(scene.class_names))
    vert_class = np.zeros(len(mesh.vertices), np.int64)
    vert_class[mesh.triangles.ravel()] = np.repeat(mesh.tri_class, 3)
    root = f"world/{name}"
    rec.log(
        f"{root}/mesh",
        rr.Mesh3D(
            vertex_positions=mesh.vertices + offset,
            triangle_indices=mesh.triangles,
            vertex_colors=colours[vert_class],
        ),
        static=True,
    )
    cid = {n: i for i, n in enumerate(scene.class_names)}
    lo = np.array([o.bbox[0] for o in scene.objects])
    hi = np.array([o.bbox[1] for o in scene.objects])
    labels = [f"{o.class_name} #{o.instance_id}" for o in scene.objects]
    rec.log(
        f"{root}/instances",
        rr.Boxes3D(
            centers=(lo + hi) / 2 + offset,
            half_sizes=(hi - lo) / 2,
            labels=labels,
            colors=colours[[cid[o.class_name] for o in scene.objects]],
        ),
        static=True,
    )
    rec.log(
        f"{root}/trajectory",
        rr.LineStrips3D([poses[:, :3, 3] + offset], colors=[[255, 60, 60]], radii=0.02),
        static=True,
    )
    K = intrinsics(render.width, render.height, render.hfov_deg)
    dt = round(1e9 / render.fps)
    for i, T in enumerate(poses):
        set_stamp(rec, render.start_ns + i * dt)
        shifted = T.copy()
        shifted[:3, 3] += offset
        log_camera(rec, f"{root}/camera", shifted, K, render.width, render.height)


def log_dataset(
    rrd_path: Path,
    scenes: Sequence[SceneConfig],
    frames: int | None = None,
    render: RenderConfig | None = None,
) -> Path:
    """Write ``rrd_path`` showing every scene of a dataset (regenerated from its seeds).

    Written whole or not at all: into a staged temporary, renamed into place once complete
    (:func:`care_maps.core.outputs.write_atomic`), so a full disk or Ctrl-C leaves the earlier file."""
    render = render or RenderConfig()

    def write(tmp: Path) -> None:
        rec = open_recording(APP_ID, tmp)
        x = 0.0
        for i, config in enumerate(scenes):
            scene = generate_scene(config)
            poses = plan_trajectory(scene, frames)
            log_scene(rec, f"scene_{i:03d}", scene, poses, np.array([x, 0.0, 0.0]), render)
            x += float(scene.room_rects[:, 2].max()) + SCENE_GAP
        rec.flush()
        rec.disconnect()

    write_atomic(Path(rrd_path), write)
    return Path(rrd_path)
