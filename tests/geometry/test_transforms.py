"""Geometry against scipy's rotations and hand-worked pinhole cases."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from care_maps.geometry.transforms import (
    backproject,
    matrix_to_quaternion,
    project,
    quaternion_to_matrix,
    transform_points,
)


def test_quaternion_round_trip_matches_scipy() -> None:
    rots = Rotation.random(50, random_state=0)
    q = rots.as_quat()
    np.testing.assert_allclose(quaternion_to_matrix(q), rots.as_matrix(), atol=1e-12)
    back = matrix_to_quaternion(rots.as_matrix())
    same = np.minimum(np.abs(back - q).max(axis=1), np.abs(back + q).max(axis=1))
    assert same.max() < 1e-9


def test_backproject_then_project_is_identity_on_valid_pixels() -> None:
    K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    depth = np.full((480, 640), 2.0, np.float32)
    depth[:10] = 0.0
    depth[20, 30] = np.nan
    pts, px = backproject(depth, K, stride=4)
    assert np.all(px[:, 1] >= 12)
    uv, z = project(pts, K)
    np.testing.assert_allclose(uv, px, atol=1e-9)
    np.testing.assert_allclose(z, 2.0)
    # Hand-worked: the principal point at depth 2 sits on the optical axis.
    centre = backproject(np.pad(np.ones((1, 1), np.float32) * 2, ((0, 0), (0, 0))), np.eye(3))[0]
    np.testing.assert_allclose(centre, [[0.0, 0.0, 2.0]])


def test_transform_points() -> None:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    T[:3, 3] = [1, 2, 3]
    np.testing.assert_allclose(
        transform_points(T, np.array([[1.0, 0, 0]])), [[1, 3, 3]], atol=1e-12
    )
