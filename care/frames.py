"""The typed record every reader produces and every encoder consumes.

Conventions, stated once for the whole project:
- time is integer nanoseconds;
- camera frames are *optical*: x right, y down, z forward;
- poses are camera-to-world 4x4 float64 matrices in metres;
- depth is float32 metres, 0 where invalid.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["DEFAULT_CAMERA_FRAME", "DEFAULT_WORLD_FRAME", "Frame"]

DEFAULT_WORLD_FRAME = "map"
"""The world frame of a recording whose transforms name none (REP 105's fixed frame)."""
DEFAULT_CAMERA_FRAME = "camera_optical_frame"
"""The camera frame of a recording whose images name none (REP 103's optical convention)."""


@dataclass(frozen=True, eq=False)
class Frame:
    """One synchronised RGB-D view.

    Attributes:
        stamp_ns: stamp of the colour image, integer nanoseconds.
        rgb: (H, W, 3) uint8 colour image.
        depth_m: (H, W) float32 depth in metres registered to the colour image, 0 = invalid.
        K: (3, 3) float64 pinhole intrinsics of the colour camera.
        cam_to_world: (4, 4) float64 optical-frame camera-to-world pose at ``stamp_ns``.
        extras: further per-pixel images of the same size keyed by name, e.g. ``"instance"``
            (uint16 instance ids, 0 = none) and ``"class"`` (uint16 class ids) in sample-world
            recordings. Empty for ordinary robot recordings.
        rgb_jpeg: the recording's own JPEG bytes that ``rgb`` was decoded from, unchanged
            (no lens undistortion, no resizing); the store keeps them instead of encoding the
            image again. None when ``rgb`` is not exactly those bytes decoded: a reader that
            changes the image after decoding it must leave this out.
    """

    stamp_ns: int
    rgb: np.ndarray
    depth_m: np.ndarray
    K: np.ndarray
    cam_to_world: np.ndarray
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    rgb_jpeg: bytes | None = None

    @property
    def height(self) -> int:
        return int(self.rgb.shape[0])

    @property
    def width(self) -> int:
        return int(self.rgb.shape[1])
