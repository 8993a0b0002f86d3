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

from care_maps.core.errors import CareError

__all__ = [
    "DEFAULT_CAMERA_FRAME",
    "DEFAULT_WORLD_FRAME",
    "FRAME_ID_FIELDS",
    "Frame",
    "FrameIdError",
    "check_frame_id",
]

DEFAULT_WORLD_FRAME = "map"
"""The world frame of a recording whose transforms name none (REP 105's fixed frame)."""
DEFAULT_CAMERA_FRAME = "camera_optical_frame"
"""The camera frame of a recording whose images name none (REP 103's optical convention)."""

FRAME_ID_FIELDS = frozenset({"frame_id", "world_frame", "camera_frame"})
"""Config fields that name a TF frame: every CLI option made from one is checked by
:func:`check_frame_id` (``care_maps.cli.options``), so ``--frame-id``, ``--world-frame`` and
``--camera-frame`` refuse the same names with the same words."""


class FrameIdError(CareError, ValueError):
    """A name tf2 would not take as a frame id."""


def check_frame_id(name: str) -> str:
    """``name`` if tf2 takes it as a frame id; otherwise :class:`FrameIdError` saying why.

    The one check of a frame id a user gives, so that a name is refused here, in one line,
    rather than printed into a command or a goal that tf2 rejects later on the robot.
    tf2's ``BufferCore::validateFrameId`` refuses an empty id and one that starts with
    ``/`` (ROS 1's ``tf_prefix`` style, which tf2 dropped); whitespace and control
    characters are refused too: no TF tree names a frame so, a shell command quoting it
    would still hand tf2 a name no publisher uses, and ``map.yaml`` would not read back.
    """
    if not name:
        reason = "it is empty (tf2 refuses an empty frame id)"
    elif name.startswith("/"):
        bare = name.lstrip("/")
        reason = "tf2 frame ids do not start with '/'" + (f" (give {bare!r})" if bare else "")
    elif any(c.isspace() for c in name):
        reason = "it holds whitespace"
    elif not name.isprintable():
        reason = "it holds control characters"
    else:
        return name
    msg = f"{name!r} is not a TF frame id: {reason}"
    raise FrameIdError(msg)


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
