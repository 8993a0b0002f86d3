"""Frames to record and ingest: synthetic ones, and the third-party RGB-D frames under
``../shared/data/rgbd`` read with their own poses and intrinsics (independently of the readers
under test)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Final

import numpy as np
from PIL import Image

from care_maps.core.frames import Frame
from care_maps.geometry.transforms import quaternion_to_matrix

K_SMALL: Final = np.array([[40.0, 0.0, 16.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]])
"""The synthetic frames' camera (32x24)."""


def smooth_rgb(i: int, h: int = 24, w: int = 32) -> np.ndarray:
    """An ``h`` x ``w`` colour image: red along x, green along y, blue from ``i``."""
    u, v = np.meshgrid(np.arange(w) * 255 // w, np.arange(h) * 255 // h)
    return np.stack([u, v, np.full_like(u, (40 * i) % 256)], axis=-1).astype(np.uint8)


def synthetic_frames(
    n: int = 6, h: int = 24, w: int = 32, dt_ns: int = 100_000_000, extras: bool = False
) -> list[Frame]:
    """A camera sliding and turning in front of a tilted plane."""
    frames = []
    for i in range(n):
        pose = np.eye(4)
        angle = 0.05 * i
        pose[:3, :3] = quaternion_to_matrix(
            np.array([0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)])
        )
        pose[:3, 3] = [0.1 * i, -0.05 * i, 1.2]
        u = np.arange(w, dtype=np.float32)[None, :]
        depth = np.broadcast_to(1.5 + 0.01 * u + 0.02 * i, (h, w)).astype(np.float32).round(3)
        ex = {}
        if extras:
            ex = {
                "instance": (np.arange(h * w).reshape(h, w) % 7).astype(np.uint16),
                "class": np.full((h, w), 1 + i % 2, np.uint16),
            }
        frames.append(
            Frame(10**9 + i * dt_ns, smooth_rgb(i, h, w), depth, K_SMALL.copy(), pose, ex)
        )
    return frames


def load_livingroom(root: Path, count: int) -> list[Frame]:
    """The first ``count`` frames of livingroom1_clean_micro with their Redwood-log poses."""
    lines = (root / "trajectory.log").read_text().split("\n")
    poses = []
    for k in range(count):
        rows = lines[5 * k + 1 : 5 * k + 5]
        poses.append(np.array([[float(x) for x in r.split()] for r in rows]))
    K = (
        np.array(json.loads((root / "camera_intrinsic.json").read_text())["intrinsic_matrix"])
        .reshape(3, 3)
        .T
    )
    frames = []
    for k in range(count):
        rgb = np.asarray(Image.open(root / "image" / f"{k:05d}.jpg").convert("RGB"))
        depth = np.asarray(Image.open(root / "depth" / f"{k:05d}.png")).astype(np.float32) / 1000.0
        frames.append(Frame(10**9 + k * 33_333_333, rgb, depth, K, poses[k]))
    return frames


def load_slambook(root: Path) -> list[Frame]:
    """slambook's 5 Kinect frames, poses ``tx ty tz qx qy qz qw`` (camera to world)."""
    K = np.array([[518.0, 0.0, 325.5], [0.0, 519.0, 253.5], [0.0, 0.0, 1.0]])
    frames = []
    for k, line in enumerate((root / "pose.txt").read_text().split("\n")[:5], start=1):
        v = np.array([float(x) for x in line.split()])
        pose = np.eye(4)
        pose[:3, :3] = quaternion_to_matrix(v[3:])
        pose[:3, 3] = v[:3]
        rgb = np.asarray(Image.open(root / "color" / f"{k}.png").convert("RGB"))
        depth = np.asarray(Image.open(root / "depth" / f"{k}.pgm")).astype(np.float32) / 1000.0
        frames.append(Frame(10**9 + k * 100_000_000, rgb, depth, K, pose))
    return frames
