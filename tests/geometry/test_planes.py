"""The seeded RANSAC plane fit against independent references: the total-least-squares
plane of the points drawn on it (scipy's SVD) and open3d's own ``segment_plane``; and the
same plane, bit for bit, whatever the BLAS thread count."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import svd
from threadpoolctl import threadpool_limits

from care_maps.geometry.planes import fit_plane


def _scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3,000 points within 5 mm of a tilted plane, then 2,000 outliers in a 2 m cube."""
    rng = np.random.default_rng(seed)
    normal = np.array([0.2, -0.3, 0.93])
    normal /= np.linalg.norm(normal)
    u = np.cross(normal, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    st = rng.uniform(-1, 1, (3000, 2))
    on = st[:, :1] * u + st[:, 1:] * v + 0.4 * normal
    on += rng.normal(0, 0.002, on.shape)
    off = rng.uniform(-1, 1, (2000, 3))
    off = off[np.abs(off @ normal - 0.4) > 0.05]
    return np.vstack([on, off]), normal, np.arange(len(on))


def test_recovers_the_least_squares_plane_of_its_points() -> None:
    points, _, truth = _scene()
    plane = fit_plane(points, 0.01, 500, np.random.default_rng(1))
    assert plane is not None
    on = points[truth]
    centred = on - on.mean(axis=0)
    reference = svd(centred, full_matrices=False)[2][-1]
    assert abs(abs(plane.normal @ reference) - 1) < 1e-6
    assert abs(np.linalg.norm(plane.normal) - 1) < 1e-12
    np.testing.assert_allclose(np.abs(on @ plane.normal + plane.offset).max(), 0.0, atol=0.01)
    assert set(truth) <= set(plane.inliers.tolist())
    assert len(plane.inliers) < len(truth) + 20  # outliers were kept 5 cm away


def test_agrees_with_open3d() -> None:
    o3d = pytest.importorskip("open3d")
    points, _, _ = _scene(3)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    model, inliers = cloud.segment_plane(0.01, 3, 500)
    theirs = np.asarray(model[:3]) / np.linalg.norm(model[:3])
    ours = fit_plane(points, 0.01, 500, np.random.default_rng(0))
    assert ours is not None
    assert abs(ours.normal @ theirs) > 0.9999
    assert abs(len(ours.inliers) - len(inliers)) <= 10


def test_same_plane_whatever_the_threads_and_the_run() -> None:
    points, _, _ = _scene(5)
    fits = []
    for threads in (1, 2, 1):
        with threadpool_limits(threads):
            p = fit_plane(points, 0.01, 300, np.random.default_rng(7))
        assert p is not None
        fits.append(p)
    for other in fits[1:]:
        assert other.normal.tobytes() == fits[0].normal.tobytes()
        assert other.offset == fits[0].offset
        assert np.array_equal(other.inliers, fits[0].inliers)


def test_degenerate_input_is_none() -> None:
    rng = np.random.default_rng(0)
    assert fit_plane(np.zeros((2, 3)), 0.01, 10, rng) is None
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    assert fit_plane(line, 0.01, 10, rng) is None
