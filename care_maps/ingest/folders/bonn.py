"""Bonn RGB-D Dynamic Dataset sequences as downloaded (``rgbd_bonn_balloon/``,
``ipb.uni-bonn.de/data/rgbd-dynamic-dataset``): TUM RGB-D's file layout (``rgb.txt``,
``depth.txt``, ``groundtruth.txt``, ``rgb/``, ``depth/``), recorded with an Asus Xtion Pro
Live and a motion-capture system.

- Detection: TUM's lists in a folder named ``rgbd_bonn_*``, the dataset's sequence names;
  the name is all that tells such a folder from a TUM sequence.
- Camera: the dataset page's calibration of the colour camera, fx 542.822841,
  fy 542.576870, cx 315.593520, cy 237.756098 at 640x480, distortion (OpenCV's k1 k2 p1 p2
  k3) 0.039903, -0.099343, -0.000730, -0.000144, 0.0. The same numbers stand in the public
  code that reads the dataset: ORB-SLAM-style ``bonn.yaml`` configs (``Camera.fx:
  542.822841`` ... ``Camera.k1: 0.039903``), and the ``bonn_sequences_dict`` of PyTorch
  loaders (``"calib": [542.822841, 542.576870, 315.593520, 237.756098]``, citing the page).
  The distortion is removed at ingest from colour and depth alike (the depth is registered
  to colour by the OpenNI driver, pixel for pixel, as TUM's). ``--intrinsics`` overrides it.
- Depth: 16-bit PNG, 5000 per metre (``DepthMapFactor: 5000.0`` in those configs; TUM's).
- Poses: ``groundtruth.txt`` holds the pose of the motion-capture markers on the sensor, in
  the motion-capture frame, not the camera's. The dataset's own
  ``compute_global_transformation.py`` (linked from the page, copied into the loaders
  above) makes a sensor point a point of the reference point cloud with
  ``T_ros @ T @ T_ros @ T_m``: ``T_ros`` (x to -x, y and z swapped) turns the
  motion-capture frame into the reference cloud's, ``T_m`` takes the camera into the marker
  frame. Its 3x3 block is a rotation times 1.0593, the scale of the registration it was
  estimated by; a camera pose is rigid, so the rotation nearest to it (its polar factor)
  and its translation are used, the depth keeping the documented 5000 per metre. The world
  frame is the reference cloud's (``bonn_world``). Interpolated at the colour stamps as
  TUM's ground truth, after the conversion.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from care_maps.ingest.folders.base import DatasetLayout
from care_maps.ingest.folders.files import Intrinsics
from care_maps.ingest.folders.tum import DEPTH_SCALE, TumLayout
from care_maps.ingest.undistort import Distortion

__all__ = ["BONN_CAMERA", "BONN_LENS", "CAMERA_IN_MARKER", "MOCAP_TO_WORLD", "BonnLayout"]

FOLDER_PREFIX = "rgbd_bonn_"
"""How every sequence of the dataset is named (``rgbd_bonn_balloon``, ...)."""
BONN_CAMERA = Intrinsics(542.822841, 542.576870, 315.593520, 237.756098, width=640,
                         height=480, source="Bonn RGB-D Dynamic calibration")  # fmt: skip
"""The dataset page's colour camera."""
BONN_LENS = Distortion("plumb_bob", (0.039903, -0.099343, -0.000730, -0.000144, 0.0))
"""The dataset page's distortion, OpenCV's k1 k2 p1 p2 k3."""
MOCAP_TO_WORLD = np.array(
    [[-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""``T_ros`` of ``compute_global_transformation.py``: the motion-capture frame to the
reference point cloud's (its own inverse)."""
_T_M = np.array([
    [1.0157, 0.1828, -0.2389, 0.0113],
    [0.0009, -0.8431, -0.6413, -0.0098],
    [-0.3009, 0.6147, -0.8085, 0.0111],
    [0.0, 0.0, 0.0, 1.0],
])  # fmt: skip
"""``T_m`` of ``compute_global_transformation.py`` as published (a similarity, scale 1.0593)."""


def _rigid(similarity: np.ndarray) -> np.ndarray:
    """The rigid transform nearest to ``similarity``: its 3x3 block's polar rotation
    (``U @ Vt`` of its SVD), its translation."""
    u, _, vt = np.linalg.svd(similarity[:3, :3])
    rigid = np.eye(4)
    rigid[:3, :3] = u @ vt
    rigid[:3, 3] = similarity[:3, 3]
    return rigid


CAMERA_IN_MARKER = MOCAP_TO_WORLD @ _rigid(_T_M)
"""The camera's optical frame in the marker frame of ``groundtruth.txt`` (``T_ros @ T_m``,
rigid part): ``marker_pose @ CAMERA_IN_MARKER`` is the camera's pose in motion-capture
coordinates."""


class BonnLayout(TumLayout):
    """A Bonn RGB-D Dynamic sequence folder (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.BONN
    world_frame: ClassVar[str] = "bonn_world"

    @classmethod
    def marks(cls, path: Path) -> bool:
        return Path(path).resolve().name.lower().startswith(FOLDER_PREFIX)

    def own_camera(self) -> tuple[Intrinsics, Distortion, float]:
        return BONN_CAMERA, BONN_LENS, DEPTH_SCALE

    def own_depth_scale(self) -> float:
        return DEPTH_SCALE

    def camera_fix(self) -> str:
        return "give the camera of these images with --intrinsics"

    def gt_pose(self, pose: np.ndarray) -> np.ndarray:
        """``T_ros @ marker @ T_ros @ T_m`` (rigid): the camera in the reference cloud's frame."""
        return MOCAP_TO_WORLD @ self.file_pose(pose) @ CAMERA_IN_MARKER

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "pose": "T_ros @ groundtruth @ T_ros @ T_m (rigid part)"}
