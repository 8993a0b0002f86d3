"""Rigid-body and pinhole geometry shared by ingest, the sample world and fuse.

Quaternions are (x, y, z, w), the ROS order. All functions are vectorised.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "BODY_FROM_OPTICAL",
    "backproject",
    "matrix_to_quaternion",
    "project",
    "quaternion_to_matrix",
    "transform_points",
]

BODY_FROM_OPTICAL = np.array(
    [
        [0.0, 0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""(4, 4) ``body_from_optical`` of one camera: its columns are the optical axes in body
axes (optical x = body -y, optical y = body -z, optical z = body x), REP 103's
``camera_link`` -> ``camera_optical_frame`` rotation."""


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) xyzw quaternions to (..., 3, 3) rotation matrices; normalises first."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    R = np.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - z * w),
            2 * (x * z + y * w),
            2 * (x * y + z * w),
            1 - 2 * (x * x + z * z),
            2 * (y * z - x * w),
            2 * (x * z - y * w),
            2 * (y * z + x * w),
            1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return R.reshape(*q.shape[:-1], 3, 3)


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices to (..., 4) xyzw quaternions with w >= 0."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=np.float64)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q.reshape(*R.shape[:-2], 4)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points."""
    return points @ T[:3, :3].T + T[:3, 3]


def backproject(
    depth_m: np.ndarray, K: np.ndarray, stride: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Optical-frame 3D points of the valid pixels of a depth image.

    Returns ``(points, pixels)``: (N, 3) float64 camera-frame points and (N, 2) int64 pixel
    coordinates (u = column, v = row) of the pixels they came from, sampled every ``stride``.
    """
    d = depth_m[::stride, ::stride]
    flat = np.flatnonzero(d > 0)  # NaN compares False; +inf is caught below
    z = d.reshape(-1)[flat].astype(np.float64)
    finite = np.isfinite(z)
    if not finite.all():
        flat, z = flat[finite], z[finite]
    v, u = np.divmod(flat, d.shape[1])  # 2-D np.nonzero is several times slower
    u = u * stride
    v = v * stride
    x = (u - K[0, 2]) * z / K[0, 0]
    y = (v - K[1, 2]) * z / K[1, 1]
    return np.stack([x, y, z], axis=1), np.stack([u, v], axis=1).astype(np.int64)


def project(points_cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N, 2) float64 and depths (N,) of optical-frame points."""
    z = points_cam[:, 2]
    safe = np.where(z > 0, z, np.inf)
    u = K[0, 0] * points_cam[:, 0] / safe + K[0, 2]
    v = K[1, 1] * points_cam[:, 1] / safe + K[1, 2]
    return np.stack([u, v], axis=1), z
