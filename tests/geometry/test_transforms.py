"""Geometry against scipy's rotations and hand-worked pinhole cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.geometry.transforms import (
    backproject,
    matrix_to_quaternion,
    project,
    quaternion_to_matrix,
    rotation_quaternion,
    transform_points,
)


def test_quaternion_round_trip_matches_scipy() -> None:
    rots = Rotation.random(50, random_state=0)
    q = rots.as_quat()
    np.testing.assert_allclose(quaternion_to_matrix(q), rots.as_matrix(), atol=1e-12)
    back = matrix_to_quaternion(rots.as_matrix())
    same = np.minimum(np.abs(back - q).max(axis=1), np.abs(back + q).max(axis=1))
    assert same.max() < 1e-9


def _yaws(n: int, rng: np.random.Generator) -> np.ndarray:
    yaw = rng.uniform(-np.pi, np.pi, n)
    out = np.zeros((n, 3, 3))
    out[:, 0, 0] = out[:, 1, 1] = np.cos(yaw)
    out[:, 1, 0] = np.sin(yaw)
    out[:, 0, 1] = -out[:, 1, 0]
    out[:, 2, 2] = 1.0
    return out


def test_rotation_quaternion_is_scipys_bit_for_bit() -> None:
    """Goals and their frames are written as scipy's quaternions were: every case of
    Markley's choice, axis-aligned matrices (ties in the choice), matrices a float32
    rounding or noise left outside the orthogonality tolerance (scipy's SVD), yaws."""
    rng = np.random.default_rng(0)
    rots = Rotation.random(4000, random_state=1).as_matrix()
    flips = np.array([np.diag(d) for d in [(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)]])
    turns = np.array([np.eye(3)[list(p)] for p in [(0, 1, 2), (1, 2, 0), (2, 0, 1)]])
    for matrices in (
        rots,
        _yaws(4000, rng),
        rots + rng.normal(0, 1e-9, rots.shape),
        rots.astype(np.float32).astype(np.float64),
        flips,
        turns,
    ):
        ours = rotation_quaternion(matrices)
        theirs = Rotation.from_matrix(matrices).as_quat()
        assert np.array_equal(ours.view(np.int64), theirs.view(np.int64))
    with pytest.raises(ValueError, match="Non-positive determinant"):
        rotation_quaternion(np.diag([1.0, 1.0, -1.0])[None])


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
