"""Fixtures of the sample-world tests: tiny scenes and recordings made once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from care_maps.world.record import make_recording
from care_maps.world.render import RenderConfig
from care_maps.world.scene import SceneConfig

TINY = SceneConfig(
    seed=11, num_rooms=2, point_density_objects=4000.0, point_density_structure=4000.0
)
"""Two rooms (so a door is crossed), with ground-truth points dense enough for cm checks."""
TINY_RENDER = RenderConfig(width=96, height=72)
TINY_FRAMES = 16


@pytest.fixture(scope="session")
def tiny_recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The same tiny scene written in every format: ``{"mcap": path, "ros2": ..., "ros1": ...}``."""
    root = tmp_path_factory.mktemp("world")
    out = {}
    for fmt, name in (("mcap", "tiny.mcap"), ("ros2", "tiny_ros2"), ("ros1", "tiny.bag")):
        path = root / name
        make_recording(path, TINY, TINY_RENDER, frames=TINY_FRAMES, fmt=fmt)
        out[fmt] = path
    return out


@pytest.fixture(scope="session")
def tiny_scene():
    """The scene behind :func:`tiny_recordings` and the poses it was rendered from."""
    from care_maps.world.scene import generate_scene
    from care_maps.world.trajectory import plan_trajectory

    scene = generate_scene(TINY)
    return scene, plan_trajectory(scene, TINY_FRAMES)
