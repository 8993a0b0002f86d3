"""Geometry of ground truth, apart from any file: boxes, polygons, rigid transforms.

Boxes are ``(center (3,), size (3,), rotation (3, 3))``: the box is the set
``center + R @ u`` with ``|u_i| <= size_i / 2`` (``R`` maps box axes to the frame's axes), so an
axis-aligned box has ``R = I`` and a box turned by ``yaw`` about z has the usual z-rotation.
Everything here is vectorised over points and boxes.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "aabb_of_boxes",
    "apply_transform",
    "box_floor_distance",
    "boxes_of_aabb",
    "label_points_by_boxes",
    "points_in_box",
    "points_in_polygon",
    "polygon_distance",
    "transform_boxes",
    "yaw_rotation",
]


def yaw_rotation(yaw: np.ndarray | float) -> np.ndarray:
    """(..., 3, 3) rotation by ``yaw`` radians about +z (counter-clockwise seen from above)."""
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((*yaw.shape, 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 2, 2] = 1.0
    return out


def boxes_of_aabb(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(center, size, rotation)`` of axis-aligned boxes given by (B, 3) corners."""
    lo = np.asarray(lo, np.float64).reshape(-1, 3)
    hi = np.asarray(hi, np.float64).reshape(-1, 3)
    return (lo + hi) / 2, hi - lo, np.broadcast_to(np.eye(3), (len(lo), 3, 3)).copy()


def _corners(center: np.ndarray, size: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(B, 8, 3) corners of each box."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    local = signs[None] * (np.asarray(size, float)[:, None, :] / 2)
    return np.asarray(center, float)[:, None, :] + np.einsum("bij,bkj->bki", rotation, local)


def aabb_of_boxes(
    center: np.ndarray, size: np.ndarray, rotation: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3) lower and upper corners of the axis-aligned bounds of each (oriented) box."""
    if len(center) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    corners = _corners(center, size, rotation)
    return corners.min(axis=1), corners.max(axis=1)


def points_in_box(
    points: np.ndarray, center: np.ndarray, size: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """(N,) bool: which points lie inside one box (boundary included)."""
    local = (np.asarray(points, np.float64) - center) @ np.asarray(rotation, np.float64)
    return np.all(np.abs(local) <= np.asarray(size, np.float64) / 2 + 1e-9, axis=1)


def label_points_by_boxes(
    points: np.ndarray,
    ids: np.ndarray,
    center: np.ndarray,
    size: np.ndarray,
    rotation: np.ndarray,
) -> np.ndarray:
    """(N,) id of the box each point lies in, 0 outside all.

    A point inside several boxes goes to the smallest (by volume): a cushion's box inside a
    sofa's keeps its points, which is what an annotator drawing nested boxes means.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    out = np.zeros(len(points), np.int32)
    if len(points) == 0 or len(center) == 0:
        return out
    volume = np.prod(np.asarray(size, np.float64), axis=1)
    lo, hi = aabb_of_boxes(center, size, rotation)
    order = np.argsort(points[:, 0], kind="stable")  # the x-slab of a box is one slice
    xs = points[order, 0]
    for b in np.argsort(-volume, kind="stable"):  # largest first, smaller ones overwrite
        near = order[np.searchsorted(xs, lo[b, 0], "left") : np.searchsorted(xs, hi[b, 0], "right")]
        inside = points_in_box(points[near], center[b], size[b], rotation[b])
        out[near[inside]] = ids[b]
    return out


def points_in_polygon(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) bool: even-odd test of (N, 2) points against one (P, 2) polygon, half-open edges
    so that points on a shared boundary are counted once."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    poly = np.asarray(poly, np.float64)
    a = poly[None, :, :]
    b = np.roll(poly, -1, axis=0)[None, :, :]
    x = xy[:, None, 0]
    y = xy[:, None, 1]
    straddles = (a[..., 1] > y) != (b[..., 1] > y)
    dy = np.where(b[..., 1] == a[..., 1], 1.0, b[..., 1] - a[..., 1])
    x_cross = a[..., 0] + (y - a[..., 1]) * (b[..., 0] - a[..., 0]) / dy
    crossings = straddles & (x < x_cross)
    return (np.count_nonzero(crossings, axis=1) % 2) == 1


def polygon_distance(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) distance of each point to a filled polygon (0 inside)."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    a = np.asarray(poly, np.float64)
    b = np.roll(a, -1, axis=0)
    ab = b - a
    t = np.einsum("npk,pk->np", xy[:, None, :] - a[None], ab) / np.maximum(
        np.einsum("pk,pk->p", ab, ab), 1e-18
    )
    nearest = a[None] + np.clip(t, 0, 1)[..., None] * ab[None]
    dist = np.linalg.norm(xy[:, None, :] - nearest, axis=2).min(axis=1)
    return np.where(points_in_polygon(xy, a), 0.0, dist)


def _hull(xy: np.ndarray) -> np.ndarray:
    """Convex hull (counter-clockwise) of a few 2-D points, monotone chain."""
    pts = sorted({(float(x), float(y)) for x, y in xy})
    if len(pts) <= 2:
        return np.asarray(pts)

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for p in seq:
            while (
                len(out) >= 2
                and (
                    (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                    - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])
                )
                <= 0
            ):
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.asarray(lower[:-1] + upper[:-1])


def box_floor_distance(
    xy: np.ndarray, center: np.ndarray, size: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """(N, B) floor-plane distance of each point to each box's footprint (0 inside it).

    The footprint is the convex hull of the box's corners projected on the floor: the
    rectangle itself for an upright box, the shadow of a tilted one.
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    corners = _corners(np.asarray(center), np.asarray(size), np.asarray(rotation))
    out = np.empty((len(xy), len(corners)))
    for b, c in enumerate(corners):
        hull = _hull(c[:, :2])
        if len(hull) < 3:  # a box with no floor area: distance to its points
            out[:, b] = np.linalg.norm(xy[:, None, :] - hull[None], axis=2).min(axis=1)
        else:
            out[:, b] = polygon_distance(xy, hull)
    return out


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (N, 3) mapped by a 4x4 rigid transform (rotation + translation)."""
    t = np.asarray(transform, np.float64)
    return np.asarray(points, np.float64) @ t[:3, :3].T + t[:3, 3]


def transform_boxes(
    transform: np.ndarray, center: np.ndarray, size: np.ndarray, rotation: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boxes mapped by a 4x4 rigid transform: centres moved, rotations composed, sizes kept."""
    t = np.asarray(transform, np.float64)
    return (
        apply_transform(t, np.asarray(center).reshape(-1, 3)),
        np.asarray(size, np.float64).reshape(-1, 3),
        np.einsum("ij,bjk->bik", t[:3, :3], np.asarray(rotation, np.float64).reshape(-1, 3, 3)),
    )
