"""Small stores written by hand through the store writer, for the map builders' tests."""

from __future__ import annotations

from pathlib import Path
from typing import Final

import numpy as np

from care_maps.core.frames import Frame
from care_maps.core.store import EncoderInfo, StoreWriter

GRID_HEIGHT: Final = 12
GRID_WIDTH: Final = 16
GRID_DIM: Final = 8
"""The grid store's views (height, width) and feature dimension."""
GRID_K: Final = np.array([[20.0, 0, 7.3], [0, 20.0, 5.7], [0, 0, 1]])
GRID_NAMES: Final = ("chair", "table", "sofa", "bed", "lamp")
"""The grid store's vocabulary."""


def looking_down(x: float, y: float, height: float) -> np.ndarray:
    """Optical frame looking straight down: x right = world x, y down = world -y."""
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = [x, y, height]
    return pose


def unit(x: np.ndarray) -> np.ndarray:
    """``x`` L2-normalised along its last axis."""
    normalised: np.ndarray = x / np.linalg.norm(x, axis=-1, keepdims=True)
    return normalised


def grid_frames(n: int, seed: int = 0) -> list[tuple[Frame, np.ndarray]]:
    """A floor at z = 0 with a box top at 0.5 m, seen from above by n shifted cameras."""
    H, W, D = GRID_HEIGHT, GRID_WIDTH, GRID_DIM
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        height = 1.5 + 0.1 * i
        depth = np.full((H, W), height, np.float32)
        depth[2:6, 3:9] = height - 0.5
        depth[0, :3] = 0.0  # invalid pixels
        depth[11, 15] = height - 2.4  # above z_max: filtered out
        pose = looking_down(0.0123 + 0.07 * i, 0.0311 - 0.05 * i, height)
        rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
        feats = unit(rng.normal(size=(3, 4, D))).astype(np.float32)
        out.append((Frame(10**9 + i * 10**8, rgb, depth, GRID_K, pose), feats))
    return out


def grid_text() -> np.ndarray:
    """The grid store's text embeddings, one per name of :data:`GRID_NAMES`."""
    return unit(np.random.default_rng(99).normal(size=(len(GRID_NAMES), GRID_DIM))).astype(
        np.float32
    )


def grid_store(path: Path, n: int = 4, seed: int = 0) -> Path:
    """A store of :func:`grid_frames` (``n`` views) with their features and the text of
    :data:`GRID_NAMES`, committed at ``path``."""
    with StoreWriter(path, EncoderInfo("test", "1", GRID_DIM, GRID_NAMES)) as writer:
        for frame, feats in grid_frames(n, seed):
            writer.add(frame, feats)
        writer.set_text(GRID_NAMES, grid_text())
        writer.commit({"source": "synthetic"})
    return path
