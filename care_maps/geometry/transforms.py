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
    "rotation_quaternion",
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
    R = np.asarray(R, dtype=np.float64)
    q = rotation_quaternion(R.reshape(-1, 3, 3))
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q.reshape(*R.shape[:-2], 4)


def rotation_quaternion(R: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices to (N, 4) xyzw quaternions, bit for bit scipy's
    ``Rotation.from_matrix(R).as_quat()`` (1.17; ``tests/geometry/test_transforms.py``
    checks it against scipy): its checks, SVD orthogonalisation of a matrix that is not
    orthogonal within 1e-12, and Markley's choice of the largest of the diagonal and the
    trace, in the same floating-point operations. Here rather than scipy's because
    ``scipy.spatial.transform`` imports most of scipy (0.2 s), which a query would pay at
    every start for a handful of goal poses.
    """
    m = np.array(R, dtype=np.float64).reshape(-1, 3, 3)
    dets = np.linalg.det(m)
    if np.any(dets <= 0):
        ind = int(np.where(dets <= 0)[0][0])
        msg = (
            "Non-positive determinant (left-handed or null coordinate frame) in rotation "
            f"matrix {ind}: {m[ind]}."
        )
        raise ValueError(msg)
    gramians = m @ np.transpose(m, (0, 2, 1))
    bent = np.where(~np.all(np.isclose(gramians, np.eye(3), atol=1e-12), axis=(1, 2)))[0]
    if len(bent):
        u, _, vt = np.linalg.svd(m[bent, :, :])
        m[bent, :, :] = u @ vt
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    decision = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], trace], axis=1)
    choice = np.argmax(decision, axis=1)  # the first of equal maxima, as scipy's loop
    q = np.empty((len(m), 4))
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        at = choice == i
        q[at, i] = 1 - trace[at] + 2 * m[at, i, i]
        q[at, j] = m[at, j, i] + m[at, i, j]
        q[at, k] = m[at, k, i] + m[at, i, k]
        q[at, 3] = m[at, k, j] - m[at, j, k]
    at = choice == 3
    q[at, 0] = m[at, 2, 1] - m[at, 1, 2]
    q[at, 1] = m[at, 0, 2] - m[at, 2, 0]
    q[at, 2] = m[at, 1, 0] - m[at, 0, 1]
    q[at, 3] = 1 + trace[at]
    norm = np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2] + q[:, 3] * q[:, 3])
    return q / norm[:, None]


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
