"""Which way a recording's camera frame points its axes, and how its poses become ours.

Every view is posed as an *optical* frame (x right, y down, z forward), the convention REP
103 prescribes for image frames (``*_optical_frame``). A robot whose TF names only the
camera's body, REP 103's body convention (x forward, y left, z up: ``camera_link`` with no
optical child), and whose driver stamps the images with it, puts every depth pixel a
quarter turn off about two axes: read as optical, the map is noise and nothing fails.

So the convention is found, not assumed (:func:`find_convention`), from what the recording
holds before any image is decoded:

- **Name.** A camera frame named ``*optical*`` is optical (REP 103's name for it); a name
  that ends like a body's (``*_link``, ``*body``, ``base_footprint``) says body; any other
  name says nothing.
- **Gravity.** The camera's axes over the poses TF gives it, in a world frame taken as z up
  (REP 103 and 105: ``map``, ``odom``, a robot's world): a camera held within about 60
  degrees of level (ground robots, handheld cameras) has its +y axis pointing down if
  optical, its +z axis pointing up if body. One of the two, clearly ahead of the other,
  decides.
- **Turning.** A camera that turns about gravity keeps its vertical axis fixed in any world,
  so where the poses turn enough to tell, the axis that stays fixed must agree with the
  gravity test: a y-down world (a SLAM trajectory's first camera frame) is not taken for a
  z-up one.

| name | geometry: optical | geometry: body | geometry unclear |
| --- | --- | --- | --- |
| optical | optical | optical | optical |
| body's | optical | body (converted) | refused |
| other | optical | refused | optical (REP 103 image frame) |

Converted only where name and geometry agree; refused, in one line naming
``--camera-convention``, where they disagree about a body or neither can tell a body-named
frame: a world that is not z up makes the geometry lie, and a wrong guess is a map of noise.
A convention given by the user is used as given.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.geometry.transforms import BODY_FROM_OPTICAL

__all__ = [
    "BODY_FROM_OPTICAL",
    "CameraConvention",
    "ConventionFound",
    "PoseConvention",
    "QuaternionOrder",
    "find_convention",
    "optical_pose",
]


class CameraConvention(StrEnum):
    """How a camera frame's axes point (REP 103)."""

    OPTICAL = "optical"
    """x right, y down, z forward (``*_optical_frame``): the images' own axes."""
    BODY = "body"
    """x forward, y left, z up (``camera_link``): a body's axes."""


class PoseConvention(StrEnum):
    """Which way a dataset's poses file maps points (a folder's ``--pose-convention``)."""

    CAMERA_TO_WORLD = "camera-to-world"
    """The camera's pose in the world (TUM, ScanNet, Redwood, Replica): a camera point in,
    a world point out."""
    WORLD_TO_CAMERA = "world-to-camera"
    """The inverse, an extrinsic matrix (COLMAP, many SfM exports): a world point in."""


class QuaternionOrder(StrEnum):
    """The order of a pose line's quaternion (a folder's ``--quaternion-order``)."""

    XYZW = "xyzw"
    """TUM's trajectory format, ROS, scipy: ``qx qy qz qw``."""
    WXYZ = "wxyz"
    """Eigen's constructor, COLMAP, many SLAM systems' own logs: ``qw qx qy qz``."""


_OPTICAL_WORD = "optical"
_BODY_NAME_ENDINGS = ("_link", "body", "base_footprint")
"""Frame name endings of a body (URDF links, REP 105's bodies): never an optical frame."""

_LEVEL = 0.5
"""cos 60 degrees: the median component along world z an axis needs to count as pointing up
(optical -y, body +z)."""
_MARGIN = 0.25
"""How far the winning convention's median must lead the other's."""
_TURNED = 0.05
"""How much farther from 1 one camera axis's mean direction must be than the other's for
the poses to show which one the camera turned about (1: never turned)."""


@dataclass(frozen=True)
class ConventionFound:
    """The convention a recording's camera frame is read in, and what decided it."""

    convention: CameraConvention
    reason: str
    """How it was decided, for ``care topics`` and the store's meta.json."""

    def as_json(self) -> dict[str, Any]:
        return {"convention": self.convention.value, "reason": self.reason}


def optical_pose(world_from_camera: np.ndarray, convention: CameraConvention) -> np.ndarray:
    """``world_from_optical`` (..., 4, 4) of a camera frame posed in ``convention``."""
    if convention is CameraConvention.BODY:
        return world_from_camera @ BODY_FROM_OPTICAL
    return world_from_camera


def _says_body(frame: str) -> bool:
    return frame.lower().endswith(_BODY_NAME_ENDINGS)


def _by_gravity(rotations: np.ndarray) -> tuple[CameraConvention | None, str]:
    """The convention the world's +z (up) picks among the camera axes, with the medians."""
    down_y = float(np.median(-rotations[:, 2, 1]))  # optical: +y points down
    up_z = float(np.median(rotations[:, 2, 2]))  # body: +z points up
    seen = f"median -y.up {down_y:.2f}, +z.up {up_z:.2f} over {len(rotations)} poses"
    if down_y >= _LEVEL and down_y >= up_z + _MARGIN:
        return CameraConvention.OPTICAL, seen
    if up_z >= _LEVEL and up_z >= down_y + _MARGIN:
        return CameraConvention.BODY, seen
    return None, seen


def _by_turning(rotations: np.ndarray) -> CameraConvention | None:
    """The convention whose vertical axis stayed the more fixed while the camera turned
    (None: it did not turn enough to tell)."""
    fixed_y = float(np.linalg.norm(rotations[:, :, 1].mean(axis=0)))
    fixed_z = float(np.linalg.norm(rotations[:, :, 2].mean(axis=0)))
    if fixed_y - fixed_z >= _TURNED:
        return CameraConvention.OPTICAL
    if fixed_z - fixed_y >= _TURNED:
        return CameraConvention.BODY
    return None


def find_convention(
    camera_frame: str, world_frame: str, world_from_camera: np.ndarray
) -> ConventionFound:
    """The convention of ``camera_frame`` from its name and its poses (N, 4, 4) in
    ``world_frame`` (N may be 0), by the table in the module's doc; one line naming
    ``--camera-convention`` where it is refused."""
    if _OPTICAL_WORD in camera_frame.lower():
        return ConventionFound(CameraConvention.OPTICAL, f"frame name {camera_frame!r}")
    rotations = np.asarray(world_from_camera, np.float64).reshape(-1, 4, 4)[:, :3, :3]
    found, seen = (None, "no pose") if not len(rotations) else _by_gravity(rotations)
    turned = _by_turning(rotations) if len(rotations) else None
    if found is not None and turned not in (None, found):
        axis = "y" if turned is CameraConvention.OPTICAL else "z"
        found, seen = None, f"{seen}, but the camera turned about its {axis} axis"
    where = f"camera frame {camera_frame!r} in world frame {world_frame!r} (taken as z up)"
    body_name = _says_body(camera_frame)
    if found is CameraConvention.OPTICAL or (found is None and not body_name):
        how = "geometry" if found else "REP 103 image frame, geometry unclear"
        return ConventionFound(CameraConvention.OPTICAL, f"{how} of {where}: {seen}")
    if found is CameraConvention.BODY and body_name:
        return ConventionFound(CameraConvention.BODY, f"frame name and geometry of {where}: {seen}")
    why = (
        "its poses point its +z axis up as a body frame's would, but its name is not a body's"
        if found is CameraConvention.BODY
        else "its name is a body's, but its poses show neither convention"
    )
    msg = (
        f"{where}: {why} ({seen}); pass --camera-convention body if the frame is x forward, "
        "y left, z up (REP 103 body, e.g. camera_link), or --camera-convention optical if it "
        "is x right, y down, z forward."
    )
    raise IngestError(msg)
