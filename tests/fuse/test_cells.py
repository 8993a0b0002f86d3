"""One view's (view, cell) samples against a plain loop over its pixels."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pytest

from care_maps.core.frames import Frame
from care_maps.fuse.cells import CellIndex, pack_cells, unpack_cells, view_samples

K = np.array([[30.0, 0, 15.2], [0, 30.0, 11.7], [0, 0, 1]])
H, W = 24, 32


def _tilted_pose(rng: np.random.Generator) -> np.ndarray:
    """A camera 1.5 m up looking forward and down, yawed at random."""
    yaw, pitch = rng.uniform(0, 2 * np.pi), rng.uniform(0.3, 0.8)
    forward = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, np.cross(forward, right), forward], axis=1)
    pose[:3, 3] = [0.37, -0.21, 1.5]
    return pose


def _looking_down() -> np.ndarray:
    """Straight down: a pixel's world height is exactly 1.5 - depth, so equal depths tie."""
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = [0.013, 0.021, 1.5]
    return pose


def _frame(
    rng: np.random.Generator, pose: np.ndarray, levels: bool, size: tuple[int, int] = (H, W)
) -> Frame:
    if levels:  # a few depth levels: whole patches of tied heights
        depth = rng.choice([0.9, 1.2, 1.45], size).astype(np.float32)
    else:
        depth = rng.uniform(0.5, 4.0, size).astype(np.float32)
    depth[0, :5] = 0.0
    depth[1, 3] = np.nan
    depth[2, 7] = np.inf
    rgb = rng.integers(0, 255, (*size, 3), dtype=np.uint8)
    return Frame(0, rgb, depth, K, pose)


def _plain(frame: Frame, feats: np.ndarray, cell: float, stride: int, z_band, sigma: float):
    """Per cell: pixel count, weight, patch counts, first highest pixel's height and colour."""
    fh, fw = feats.shape[:2]
    H, W = frame.height, frame.width
    cells: dict = defaultdict(lambda: {"n": 0, "w": 0.0, "patches": defaultdict(int), "top": None})
    for v in range(0, H, stride):
        for u in range(0, W, stride):
            z = float(frame.depth_m[v, u])
            if not (z > 0 and math.isfinite(z)):
                continue
            p = frame.cam_to_world @ np.array(
                [(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z, 1.0]
            )
            if not z_band[0] <= p[2] <= z_band[1]:
                continue
            c = cells[(math.floor(p[0] / cell), math.floor(p[1] / cell))]
            c["n"] += 1
            c["w"] += math.exp(-(z**2) / (2 * sigma**2))
            c["patches"][(v * fh // H) * fw + u * fw // W] += 1
            if c["top"] is None or p[2] > c["top"][0]:  # strictly higher: the first one wins
                c["top"] = (p[2], tuple(frame.rgb[v, u]))
    return cells


@pytest.mark.parametrize(
    ("pose", "levels", "stride", "fmap", "size"),
    [
        ("tilted", False, 1, (3, 4), (H, W)),  # more cells than patches: patch dots
        ("tilted", False, 3, (6, 8), (H, W)),
        ("down", True, 1, (12, 16), (H, W)),  # fewer cells than patches; tied heights
        ("down", True, 2, (2, 2), (H, W)),
        ("tilted", False, 3, (5, 7), (25, 31)),  # nothing divides anything
        ("down", True, 4, (4, 3), (23, 29)),
    ],
)
def test_view_samples_equal_a_plain_pixel_loop(pose, levels, stride, fmap, size) -> None:
    rng = np.random.default_rng(stride + fmap[0])
    pose = _tilted_pose(rng) if pose == "tilted" else _looking_down()
    frame = _frame(rng, pose, levels, size)
    feats = rng.normal(size=(*fmap, 6)).astype(np.float32)
    text = rng.normal(size=(5, 6)).astype(np.float32)
    band = (-0.1, 0.9)
    got = view_samples(
        frame, feats, cell_size=0.1, stride=stride, z_min=band[0], z_max=band[1], sigma_z=2.5,
        text=text,
    )  # fmt: skip
    ref = _plain(frame, feats, 0.1, stride, band, 2.5)
    assert got.size == len(ref) > 3
    ix, iy = unpack_cells(got.keys)
    assert list(zip(ix.tolist(), iy.tolist(), strict=True)) == sorted(ref)
    flat = feats.reshape(-1, feats.shape[-1]).astype(np.float64)
    for i, key in enumerate(sorted(ref)):
        r = ref[key]
        assert got.num_pixels[i] == r["n"]
        assert got.weight[i] == pytest.approx(r["w"], rel=1e-6)
        mean = sum(n * flat[p] for p, n in r["patches"].items())
        mean /= np.linalg.norm(mean)
        np.testing.assert_allclose(got.feature[i], mean, atol=1e-6)
        np.testing.assert_allclose(got.dots[i], text @ mean, atol=1e-5)
        assert got.top_z[i] == pytest.approx(r["top"][0], abs=1e-6)
        assert tuple(got.top_rgb[i]) == r["top"][1]


def test_view_with_no_pixel_in_the_band_has_no_samples() -> None:
    frame = _frame(np.random.default_rng(0), _looking_down(), True)
    got = view_samples(frame, np.ones((2, 2, 3), np.float32), cell_size=0.1, z_min=5.0, sigma_z=2.5)
    assert got.size == 0
    assert got.feature.shape == (0, 3)


def test_cell_index_ids_follow_first_appearance() -> None:
    index = CellIndex()
    first = pack_cells(np.array([-3, 0, 2]), np.array([5, -1, 0]))
    second = pack_cells(np.array([-4, 0, 2]), np.array([0, -1, 7]))
    np.testing.assert_array_equal(index.lookup(first), [0, 1, 2])
    np.testing.assert_array_equal(index.lookup(np.sort(second)), [3, 1, 4])
    ix, iy = unpack_cells(index.keys_by_id())
    assert list(zip(ix.tolist(), iy.tolist(), strict=True)) == [
        (-3, 5),
        (0, -1),
        (2, 0),
        (-4, 0),
        (2, 7),
    ]


@pytest.mark.parametrize("band", [(-np.inf, np.inf), (-np.inf, 0.9), (-0.1, np.inf)])
def test_an_open_band_keeps_every_finite_depth_only(band) -> None:
    """Infinite depths give infinite heights, which only an open band would let through."""
    rng = np.random.default_rng(11)
    frame = _frame(rng, _tilted_pose(rng), False)
    feats = rng.normal(size=(3, 4, 6)).astype(np.float32)
    got = view_samples(frame, feats, cell_size=0.1, z_min=band[0], z_max=band[1], sigma_z=2.5)
    ref = _plain(frame, feats, 0.1, 1, band, 2.5)
    ix, iy = unpack_cells(got.keys)
    assert list(zip(ix.tolist(), iy.tolist(), strict=True)) == sorted(ref)
    assert got.num_pixels.tolist() == [ref[key]["n"] for key in sorted(ref)]
    if np.isinf(band).all():  # every positive finite depth: all but the 5 zeros, NaN, inf
        assert int(got.num_pixels.sum()) == int(np.isfinite(frame.depth_m).sum()) - 5


@pytest.mark.slow
def test_depth_in_any_layout_gives_the_same_samples() -> None:
    """Big-endian, integer-valued or strided depth images: the same samples, bit for bit."""
    rng = np.random.default_rng(5)
    frame = _frame(rng, _tilted_pose(rng), True)
    feats = rng.normal(size=(3, 4, 6)).astype(np.float32)
    band = {"cell_size": 0.1, "z_min": -0.1, "z_max": 0.9, "sigma_z": 2.5}
    ref = view_samples(frame, feats, **band)
    wide = np.zeros((H, 2 * W), np.float32)
    wide[:, ::2] = frame.depth_m
    for depth in (frame.depth_m.astype(">f4"), frame.depth_m.astype(np.float64), wide[:, ::2]):
        other = Frame(0, frame.rgb, depth, K, frame.cam_to_world)
        got = view_samples(other, feats, **band)
        for name in ("keys", "weight", "feature", "num_pixels", "top_z", "top_rgb"):
            assert getattr(got, name).tobytes() == getattr(ref, name).tobytes(), name
