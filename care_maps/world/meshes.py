"""Mesh primitives of the sample world: axis-aligned boxes and cylinders as triangle soups.

Every object is a composite of :class:`Part`s; a scene is one big triangle mesh with a
per-triangle instance id, class id and colour, which is what the ray caster needs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = ["Mesh", "Part", "merge_meshes", "part_mesh", "rotate_part", "sample_surface"]

CYLINDER_SEGMENTS = 16


@dataclass(frozen=True)
class Part:
    """A box or a cylinder, axis-aligned, in an object's local frame or the world frame.

    A box spans ``center +- size / 2``; a cylinder has diameter ``size`` across its two
    radial axes and length ``size`` along ``axis`` (so ``size`` is always its bounding box).
    """

    kind: Literal["box", "cylinder"]
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    colour: tuple[float, float, float]
    """Linear RGB in [0, 1]."""
    axis: int = 2
    """Cylinder axis (0 = x, 1 = y, 2 = z); ignored for boxes."""

    @property
    def bbox(self) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(self.center, np.float64)
        h = np.asarray(self.size, np.float64) / 2
        return c - h, c + h


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle soup with per-triangle labels and colours."""

    vertices: np.ndarray
    """(V, 3) float64."""
    triangles: np.ndarray
    """(T, 3) int64, counter-clockwise seen from outside."""
    tri_instance: np.ndarray
    """(T,) int32 instance id, 0 = structure."""
    tri_class: np.ndarray
    """(T,) int32 class id."""
    tri_colour: np.ndarray
    """(T, 3) float32 linear RGB."""

    @property
    def tri_area(self) -> np.ndarray:
        v = self.vertices[self.triangles]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


_BOX_V = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], np.float64
)
_BOX_T = np.array(
    [
        [0, 1, 3], [0, 3, 2],  # -x
        [4, 6, 7], [4, 7, 5],  # +x
        [0, 4, 5], [0, 5, 1],  # -y
        [2, 3, 7], [2, 7, 6],  # +y
        [0, 2, 6], [0, 6, 4],  # -z
        [1, 5, 7], [1, 7, 3],  # +z
    ],
    np.int64,
)  # fmt: skip


def _cylinder_unit() -> tuple[np.ndarray, np.ndarray]:
    """Unit cylinder along z: radius 0.5, z in [-0.5, 0.5]."""
    n = CYLINDER_SEGMENTS
    a = 2 * np.pi * np.arange(n) / n
    ring = np.stack([0.5 * np.cos(a), 0.5 * np.sin(a)], axis=1)
    bottom = np.column_stack([ring, np.full(n, -0.5)])
    top = np.column_stack([ring, np.full(n, 0.5)])
    v = np.vstack([bottom, top, [[0, 0, -0.5], [0, 0, 0.5]]])
    i = np.arange(n)
    j = (i + 1) % n
    side = np.concatenate([np.stack([i, j, n + j], 1), np.stack([i, n + j, n + i], 1)])
    cap_b = np.stack([np.full(n, 2 * n), j, i], 1)
    cap_t = np.stack([np.full(n, 2 * n + 1), n + i, n + j], 1)
    return v, np.concatenate([side, cap_b, cap_t]).astype(np.int64)


_CYL_V, _CYL_T = _cylinder_unit()


def part_mesh(part: Part) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3), triangles (T, 3))`` of one part."""
    if part.kind == "box":
        v = _BOX_V * np.asarray(part.size)
        return v + np.asarray(part.center), _BOX_T.copy()
    v = _CYL_V.copy()
    # Move the unit cylinder's z axis onto the part's axis, then scale by its bounding box.
    order = {0: [2, 0, 1], 1: [0, 2, 1], 2: [0, 1, 2]}[part.axis]
    v = v[:, order]
    t = _CYL_T.copy() if part.axis != 1 else _CYL_T[:, ::-1].copy()
    return v * np.asarray(part.size) + np.asarray(part.center), t


def rotate_part(part: Part, quarter_turns: int, offset: np.ndarray) -> Part:
    """The part turned by ``quarter_turns * 90`` degrees about z, then shifted by ``offset``."""
    k = quarter_turns % 4
    cx, cy, cz = part.center
    sx, sy, sz = part.size
    for _ in range(k):
        cx, cy = -cy, cx
        sx, sy = sy, sx
    axis = part.axis
    if k % 2 == 1 and axis in (0, 1):
        axis = 1 - axis
    centre = (float(cx + offset[0]), float(cy + offset[1]), float(cz + offset[2]))
    return Part(part.kind, centre, (sx, sy, sz), part.colour, axis)


def merge_meshes(
    parts_by_label: list[tuple[int, int, list[Part]]],
) -> Mesh:
    """One :class:`Mesh` from ``(instance_id, class_id, parts)`` groups."""
    verts, tris, inst, cls, col = [], [], [], [], []
    base = 0
    for instance_id, class_id, parts in parts_by_label:
        for part in parts:
            v, t = part_mesh(part)
            verts.append(v)
            tris.append(t + base)
            base += len(v)
            inst.append(np.full(len(t), instance_id, np.int32))
            cls.append(np.full(len(t), class_id, np.int32))
            col.append(np.tile(np.asarray(part.colour, np.float32), (len(t), 1)))
    return Mesh(
        np.vstack(verts),
        np.vstack(tris),
        np.concatenate(inst),
        np.concatenate(cls),
        np.vstack(col),
    )


def sample_surface(
    mesh: Mesh, density: np.ndarray | float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Points on the mesh surface, ``ceil(area * density)`` per triangle (so every triangle,
    however small, is covered), uniform within each. Returns (P, 3) float32 points and the
    (P,) index of the triangle each came from."""
    area = mesh.tri_area
    counts = np.ceil(area * np.broadcast_to(density, area.shape)).astype(np.int64)
    tri_idx = np.repeat(np.arange(len(area)), counts)
    r1 = np.sqrt(rng.random(len(tri_idx)))
    r2 = rng.random(len(tri_idx))
    v = mesh.vertices[mesh.triangles[tri_idx]]
    pts = (
        (1 - r1)[:, None] * v[:, 0]
        + (r1 * (1 - r2))[:, None] * v[:, 1]
        + (r1 * r2)[:, None] * v[:, 2]
    )
    return pts.astype(np.float32), tri_idx
