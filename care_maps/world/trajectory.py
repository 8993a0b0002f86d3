"""An exploration trajectory through a scene's navigation zone.

The camera tours the rooms depth-first through the doors (so every room is visited), turns
a full circle at each room's centre the first time it gets there, faces where it goes in
between with a gentle sideways sway of the gaze, and moves smoothly: the key poses are
joined by straight moves and turns on the spot, resampled densely, smoothed with a Gaussian
and then sampled at equal steps of *effort* (metres moved plus ``TURN_RADIUS`` metres per
radian turned), so frames are spread over both moving and looking around. All positions
stay inside the navigation zone the furniture was kept out of.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from care_maps.world.scene import Scene

__all__ = ["TrajectoryConfig", "camera_pose", "plan_trajectory", "room_tour"]

TURN_RADIUS = 0.6
"""Metres of effort per radian of turning."""


@dataclass(frozen=True)
class TrajectoryConfig:
    """Shape of the camera path."""

    camera_height: float = 1.5
    """Metres above the floor."""
    pitch_deg: float = -15.0
    """Mean camera pitch (negative looks down)."""
    pitch_sway_deg: float = 5.0
    """Amplitude of the slow up-and-down look."""
    yaw_sway_rad: float = 0.3
    """Amplitude of the sideways look while moving."""
    frames_per_room: int = 25
    """Frames per room when the number of frames is not given."""


def camera_pose(position: np.ndarray, yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """(N, 4, 4) optical-frame camera-to-world poses (x right, y down, z forward) of cameras
    at ``position`` (N, 3) looking along ``yaw`` (about world z) tilted by ``pitch``."""
    yaw = np.asarray(yaw, np.float64)
    pitch = np.asarray(pitch, np.float64)
    forward = np.stack(
        [np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], -1
    )
    right = np.stack([np.sin(yaw), -np.cos(yaw), np.zeros_like(yaw)], -1)
    down = np.cross(forward, right)
    T = np.tile(np.eye(4), (len(yaw), 1, 1))
    T[:, :3, 0] = right
    T[:, :3, 1] = down
    T[:, :3, 2] = forward
    T[:, :3, 3] = position
    return T


def room_tour(scene: Scene) -> list[tuple[str, int]]:
    """Depth-first tour over the door graph from room 0: ``("room", i)`` / ``("door", k)``
    steps, returning along the way it came so every room is reached through doors."""
    adj: dict[int, list[tuple[int, int]]] = {i: [] for i in range(len(scene.rooms))}
    for k, d in enumerate(scene.doors):
        a, b = d.rooms
        adj[a].append((b, k))
        adj[b].append((a, k))
    seen = {0}
    steps: list[tuple[str, int]] = [("room", 0)]

    def visit(room: int) -> None:
        for other, k in sorted(adj[room]):
            if other in seen:
                continue
            seen.add(other)
            steps.extend([("door", k), ("room", other)])
            visit(other)
            steps.extend([("door", k), ("room", room)])

    visit(0)
    return steps


def _key_path(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Dense (M, 2) positions and (M,) unwrapped yaw along the tour at 2 cm of effort."""
    centres = (scene.room_rects[:, :2] + scene.room_rects[:, 2:]) / 2
    points: list[np.ndarray] = [centres[0]]
    spin_at: set[int] = {0}
    rooms_seen: set[int] = {0}
    for kind, idx in room_tour(scene)[1:]:
        if kind == "door":
            door = scene.doors[idx]
            a, b = door.points(0.6)
            if np.linalg.norm(a - points[-1]) > np.linalg.norm(b - points[-1]):
                a, b = b, a
            points.extend([a, b])
        else:
            points.append(centres[idx])
            if idx not in rooms_seen:
                rooms_seen.add(idx)
                spin_at.add(len(points) - 1)
    step = 0.02
    pos: list[np.ndarray] = []
    yaw: list[float] = []
    heading = 0.0
    for i, p in enumerate(points):
        if i > 0:
            delta = p - points[i - 1]
            dist = float(np.linalg.norm(delta))
            if dist > 1e-6:
                target = float(np.arctan2(delta[1], delta[0]))
                turn = (target - heading + np.pi) % (2 * np.pi) - np.pi
                n_turn = max(1, int(abs(turn) * TURN_RADIUS / step))
                yaw.extend(heading + turn * np.arange(1, n_turn + 1) / n_turn)
                pos.extend([points[i - 1]] * n_turn)
                heading += turn
                n = max(1, int(dist / step))
                pos.extend(points[i - 1] + delta * (np.arange(1, n + 1) / n)[:, None])
                yaw.extend([heading] * n)
        else:
            pos.append(p)
            yaw.append(heading)
        if i in spin_at:
            n = int(2 * np.pi * TURN_RADIUS / step)
            yaw.extend(heading + 2 * np.pi * np.arange(1, n + 1) / n)
            pos.extend([p] * n)
            heading += 2 * np.pi
    return np.asarray(pos), np.asarray(yaw)


def plan_trajectory(
    scene: Scene, num_frames: int | None = None, config: TrajectoryConfig | None = None
) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses of an exploration of ``scene``."""
    from scipy.ndimage import gaussian_filter1d

    config = config or TrajectoryConfig()
    n = config.frames_per_room * len(scene.rooms) if num_frames is None else num_frames
    pos, yaw = _key_path(scene)
    # effort of each dense sample, then smoothing (sigma ~ 0.2 m of effort) and resampling
    smooth_pos = gaussian_filter1d(pos, 10, axis=0, mode="nearest")
    smooth_yaw = gaussian_filter1d(yaw, 10, mode="nearest")
    s = np.linspace(0, len(pos) - 1, n)
    idx = np.arange(len(pos))
    px = np.interp(s, idx, smooth_pos[:, 0])
    py = np.interp(s, idx, smooth_pos[:, 1])
    psi = np.interp(s, idx, smooth_yaw)
    effort = s * 0.02
    step_moves = np.r_[0, np.linalg.norm(np.diff(pos, axis=0), axis=1) > 0].astype(float)
    moving = np.interp(s, idx, gaussian_filter1d(step_moves, 25, mode="nearest"))
    psi = psi + config.yaw_sway_rad * moving * np.sin(2 * np.pi * effort / 3.0)
    pitch = np.deg2rad(config.pitch_deg + config.pitch_sway_deg * np.sin(2 * np.pi * effort / 4.1))
    position = np.stack([px, py, np.full(n, config.camera_height)], axis=1)
    return camera_pose(position, psi, pitch)
