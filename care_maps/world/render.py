"""Ray-cast RGB-D and label images of a scene with open3d's ``RaycastingScene``.

One ray per pixel through the pixel's integer coordinates (the convention of
:func:`care_maps.geometry.transforms.backproject`), with a camera-frame direction whose z is 1, so the hit
distance *is* the depth. The triangle hit gives the instance and class ids; its normal
gives Lambertian shading (a light from above plus a head light), and a value noise fixed to
world positions gives each surface a texture that stays put as the camera moves.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from care_maps.core.frames import Frame
from care_maps.world.scene import Scene

__all__ = ["RenderConfig", "Renderer", "intrinsics"]

LIGHT = np.array([0.35, 0.25, 1.0]) / np.linalg.norm([0.35, 0.25, 1.0])


@dataclass(frozen=True)
class RenderConfig:
    """Camera and image settings."""

    width: int = 640
    """Image width in pixels."""
    height: int = 480
    """Image height in pixels."""
    hfov_deg: float = 70.0
    """Horizontal field of view."""
    max_depth: float = 10.0
    """Depth beyond this is invalid (0), like a real sensor's range; colour and labels
    still show what is there."""
    texture: float = 0.12
    """Relative amplitude of the surface texture noise."""
    fps: float = 5.0
    """Frame rate of the recording (stamps are 1/fps apart)."""
    start_ns: int = 1_700_000_000_000_000_000
    """Stamp of the first frame."""
    threads: int = 0
    """Ray-casting threads (0 = all)."""


def intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """(3, 3) pinhole intrinsics with square pixels and the centre between the middle pixels."""
    f = (width / 2) / np.tan(np.deg2rad(hfov_deg) / 2)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])


def _hash01(cells: np.ndarray) -> np.ndarray:
    """Deterministic value in [0, 1) per integer 3-vector (vectorised integer hash)."""
    c = cells.astype(np.int64).astype(np.uint64)
    h = (
        c[..., 0] * np.uint64(73856093)
        ^ c[..., 1] * np.uint64(19349663)
        ^ c[..., 2] * np.uint64(83492791)
    )
    h ^= h >> np.uint64(13)
    h *= np.uint64(0x5BD1E995)
    h ^= h >> np.uint64(15)
    return (h & np.uint64(0xFFFFFF)).astype(np.float64) / float(0xFFFFFF)


class Renderer:
    """Renders views of one scene; build once, call :meth:`render` per pose."""

    def __init__(self, scene: Scene, config: RenderConfig | None = None) -> None:
        import open3d as o3d

        self.scene = scene
        self.config = config or RenderConfig()
        mesh = scene.mesh
        self._rc = o3d.t.geometry.RaycastingScene()
        # dtype and device stated (open3d's stubs require them): the array's own, on the CPU,
        # as Tensor(array) chooses them
        self._cpu = o3d.core.Device("CPU:0")
        self._rc.add_triangles(
            o3d.core.Tensor(mesh.vertices.astype(np.float32), o3d.core.float32, self._cpu),
            o3d.core.Tensor(mesh.triangles.astype(np.uint32), o3d.core.uint32, self._cpu),
        )
        self._o3d = o3d
        self.K = intrinsics(self.config.width, self.config.height, self.config.hfov_deg)
        u, v = np.meshgrid(np.arange(self.config.width), np.arange(self.config.height))
        self._dirs_cam = np.stack(
            [
                (u - self.K[0, 2]) / self.K[0, 0],
                (v - self.K[1, 2]) / self.K[1, 1],
                np.ones_like(u, float),
            ],
            axis=-1,
        )
        self._tri_instance = np.append(mesh.tri_instance, 0).astype(np.uint16)
        self._tri_class = np.append(mesh.tri_class, 0).astype(np.uint16)
        self._tri_colour = np.vstack([mesh.tri_colour, np.zeros((1, 3), np.float32)])

    def render(self, cam_to_world: np.ndarray, stamp_ns: int = 0) -> Frame:
        """One :class:`Frame` with ``instance`` and ``class`` extras."""
        T = np.asarray(cam_to_world, np.float64)
        dirs = self._dirs_cam @ T[:3, :3].T
        rays = np.concatenate([np.broadcast_to(T[:3, 3], dirs.shape), dirs], axis=-1).astype(
            np.float32
        )
        rays_t = self._o3d.core.Tensor(rays, self._o3d.core.float32, self._cpu)
        ans = self._rc.cast_rays(rays_t, nthreads=self.config.threads)
        t = ans["t_hit"].numpy()
        hit = np.isfinite(t)
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        prim = np.where(hit, prim, len(self._tri_instance) - 1)
        normal = ans["primitive_normals"].numpy().astype(np.float64)
        unit = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
        facing = np.sum(normal * unit, axis=-1)
        normal = np.where(facing[..., None] > 0, -normal, normal)
        shade = 0.3 + 0.45 * np.clip(normal @ LIGHT, 0, 1) + 0.3 * np.abs(facing)
        points = T[:3, 3] + np.where(hit, t, 0)[..., None] * dirs
        tex = 0.6 * _hash01(np.floor(points / 0.04)) + 0.4 * _hash01(np.floor(points / 0.011) + 7)
        shade = shade * (1 + self.config.texture * (2 * tex - 1))
        linear = self._tri_colour[prim] * shade[..., None]
        rgb = np.clip(255 * np.clip(linear, 0, 1) ** (1 / 2.2), 0, 255).astype(np.uint8)
        rgb[~hit] = 0
        depth = np.where(hit & (t <= self.config.max_depth), t, 0).astype(np.float32)
        return Frame(
            stamp_ns=int(stamp_ns),
            rgb=rgb,
            depth_m=depth,
            K=self.K.copy(),
            cam_to_world=T.copy(),
            extras={"instance": self._tri_instance[prim], "class": self._tri_class[prim]},
        )

    def render_all(self, poses: np.ndarray) -> Iterator[Frame]:
        """Frames of ``poses`` (N, 4, 4), stamped at the configured frame rate."""
        dt = round(1e9 / self.config.fps)
        for i, T in enumerate(poses):
            yield self.render(T, self.config.start_ns + i * dt)
