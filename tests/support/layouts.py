"""The living-room frames laid out as each public dataset ships its frames, in that dataset's
own conventions (file names, image formats, depth scale, pose file format, timing), written
here independently of the readers under test.

- Redwood / ICL-NUIM: ``image/%05d.jpg``, ``depth/%05d.png`` (millimetres), ``trajectory.log``
  (``i i i+1`` and a 4x4 camera-to-world per frame), Open3D's ``camera_intrinsic.json``.
- TUM RGB-D: ``rgb/<stamp>.png``, ``depth/<stamp>.png`` (5000 per metre) at stamps a few
  milliseconds off the colour ones, ``rgb.txt``/``depth.txt`` with TUM's three comment lines,
  ``groundtruth.txt`` at 100 Hz on its own clock (the trajectory interpolated there), stamps
  as epoch seconds with six decimals. The folder's name names no sensor, so the tests give
  the camera (``--intrinsics primesense``: the living room's own, fx = fy = 525, 319.5,
  239.5); without it the folder is refused.
- ETH3D SLAM: TUM's lists at the same stamps for colour and depth (the rig is synchronised),
  ``associated.txt``, ``groundtruth.txt`` at the image stamps, ``calibration.txt`` with the
  living room's camera (``525 525 319.5 239.5``).
- Bonn RGB-D Dynamic: TUM's layout in a folder named ``rgbd_bonn_*``, its ground truth the
  pose of the motion-capture markers: the camera pose taken back through the dataset's
  ``compute_global_transformation.py`` (``T_ros``, ``T_m``; written out here). The frames
  are the living room's, not Bonn's camera: tests give ``--intrinsics`` to read them.
- 7-Scenes: ``seq-01/frame-%06d.color.png``, ``.depth.png`` (millimetres, 65535 for no
  depth), ``.pose.txt`` (4x4 camera-to-world, tab-separated rows as the release's).
- Replica (NICE-SLAM): ``Replica/cam_params.json`` above the scene (the living room's camera:
  the real renders are 1200x680, these frames 640x480), ``room0/results/frame%06d.jpg``,
  ``depth%06d.png`` (6553.5 per metre), ``traj.txt`` (16 numbers a line, row-major).
- Generic: ``rgb/``, ``depth/`` (millimetres), ``poses.txt`` (TUM trajectory format),
  ``intrinsics.json``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation, Slerp

from care_maps.core.frames import Frame

TUM_EPOCH = 1305031102.0
"""Seconds: where the TUM layout's clock starts (the epoch of freiburg1_xyz's first stamp)."""
TUM_DEPTH_OFFSET_S = 0.007
"""Depth stamps lag the colour ones by this much, as the Kinect's two streams do."""
TUM_GT_RATE_HZ = 100.0


def _png16(path: Path, depth_m: np.ndarray, scale: float) -> None:
    values = np.round(depth_m.astype(np.float64) * scale)
    assert values.max() <= np.iinfo(np.uint16).max, "depth beyond the format's range"
    Image.fromarray(values.astype(np.uint16)).save(path, compress_level=1)


def _image(path: Path, rgb: np.ndarray) -> None:
    """PNG (fast, light compression), or JPEG (quality 95) for a ``.jpg`` name, as the
    dataset stores its colour."""
    options: dict[str, Any] = {"quality": 95} if path.suffix == ".jpg" else {"compress_level": 1}
    Image.fromarray(rgb).save(path, **options)


def _tum_row(T: np.ndarray) -> str:
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    return " ".join(f"{v:.6f}" for v in (*T[:3, 3], *q))


def redwood(folder: Path, frames: list[Frame]) -> Path:
    (folder / "image").mkdir(parents=True)
    (folder / "depth").mkdir()
    log = []
    for i, f in enumerate(frames):
        _image(folder / "image" / f"{i:05d}.jpg", f.rgb)
        _png16(folder / "depth" / f"{i:05d}.png", f.depth_m, 1000.0)
        log.append(f"{i} {i} {i + 1}")
        log += [" ".join(f"{v:.8f}" for v in row) for row in f.cam_to_world]
    (folder / "trajectory.log").write_text("\n".join(log) + "\n")
    K = frames[0].K
    intrinsic = {"width": frames[0].width, "height": frames[0].height,
                 "intrinsic_matrix": K.T.ravel().tolist()}  # fmt: skip
    (folder / "camera_intrinsic.json").write_text(json.dumps(intrinsic, indent="\t"))
    return folder


def tum_seconds(frame: Frame, first: Frame) -> float:
    """The frame's TUM stamp: epoch seconds, six decimals (microseconds)."""
    return round(TUM_EPOCH + (frame.stamp_ns - first.stamp_ns) / 1e9, 6)


def tum(
    folder: Path, frames: list[Frame], gt_pose: Callable[[np.ndarray], np.ndarray] | None = None
) -> Path:
    """TUM's layout; ``gt_pose`` turns a camera pose into what ``groundtruth.txt`` holds
    (another body's pose, as Bonn's markers)."""
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    header = "# {what}\n# file: 'rgbd_dataset_livingroom.bag'\n# timestamp filename\n"
    rgb, depth = [header.format(what="color images")], [header.format(what="depth maps")]
    for f in frames:
        t = tum_seconds(f, frames[0])
        td = round(t + TUM_DEPTH_OFFSET_S, 6)
        _image(folder / "rgb" / f"{t:.6f}.png", f.rgb)
        _png16(folder / "depth" / f"{td:.6f}.png", f.depth_m, 5000.0)
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png\n")
        depth.append(f"{td:.6f} depth/{td:.6f}.png\n")
    (folder / "rgb.txt").write_text("".join(rgb))
    (folder / "depth.txt").write_text("".join(depth))
    # the ground truth at its own rate: the trajectory interpolated (linear translation,
    # slerp) at 100 Hz over the images' span, so most images fall between two samples
    times = np.array([tum_seconds(f, frames[0]) for f in frames]) - TUM_EPOCH
    poses = np.stack([f.cam_to_world for f in frames])
    period = 1 / TUM_GT_RATE_HZ
    # the last image's stamp closes the samples (not a sample a rounding step before it)
    gt_times = np.r_[np.arange(times[0], times[-1] - period / 2, period), times[-1]]
    inside = gt_times
    rotations = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))(inside)
    lines = ["# ground truth trajectory\n# file: 'rgbd_dataset_livingroom.bag'\n"
             "# timestamp tx ty tz qx qy qz qw\n"]  # fmt: skip
    for k, t in enumerate(gt_times):
        T = np.eye(4)
        T[:3, :3] = rotations[k].as_matrix()
        T[:3, 3] = [np.interp(inside[k], times, poses[:, a, 3]) for a in range(3)]
        lines.append(f"{TUM_EPOCH + t:.4f} {_tum_row(gt_pose(T) if gt_pose else T)}\n")
    (folder / "groundtruth.txt").write_text("".join(lines))
    return folder


def replica(release: Path, frames: list[Frame], scene: str = "room0") -> Path:
    folder = release / scene
    (folder / "results").mkdir(parents=True)
    K = frames[0].K
    camera = {"w": frames[0].width, "h": frames[0].height, "fx": K[0, 0], "fy": K[1, 1],
              "cx": K[0, 2], "cy": K[1, 2], "scale": 6553.5}  # fmt: skip
    (release / "cam_params.json").write_text(json.dumps({"camera": camera}, indent=4))
    lines = []
    for i, f in enumerate(frames):
        _image(folder / "results" / f"frame{i:06d}.jpg", f.rgb)
        _png16(folder / "results" / f"depth{i:06d}.png", f.depth_m, 6553.5)
        lines.append(" ".join(f"{v:.18e}" for v in f.cam_to_world.ravel()))
    (folder / "traj.txt").write_text("\n".join(lines) + "\n")
    return folder


def generic(folder: Path, frames: list[Frame]) -> Path:
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    lines = []
    for i, f in enumerate(frames):
        _image(folder / "rgb" / f"{i:06d}.png", f.rgb)
        _png16(folder / "depth" / f"{i:06d}.png", f.depth_m, 1000.0)
        seconds = f"{f.stamp_ns // 10**9}.{f.stamp_ns % 10**9:09d}"
        lines.append(f"{seconds} {_tum_row(f.cam_to_world)}\n")
    (folder / "poses.txt").write_text("".join(lines))
    K = frames[0].K
    intrinsics = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
                  "width": frames[0].width, "height": frames[0].height, "depth_scale": 1000.0}  # fmt: skip
    (folder / "intrinsics.json").write_text(json.dumps(intrinsics))
    return folder


def eth3d(folder: Path, frames: list[Frame]) -> Path:
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    rgb, depth, associated, gt = [], [], [], ["# timestamp tx ty tz qx qy qz qw\n"]
    for f in frames:
        t = f"{tum_seconds(f, frames[0]):.6f}"
        _image(folder / "rgb" / f"{t}.png", f.rgb)
        _png16(folder / "depth" / f"{t}.png", f.depth_m, 5000.0)
        rgb.append(f"{t} rgb/{t}.png\n")
        depth.append(f"{t} depth/{t}.png\n")
        associated.append(f"{t} rgb/{t}.png {t} depth/{t}.png\n")
        gt.append(f"{t} {_tum_row(f.cam_to_world)}\n")
    for name, lines in (("rgb.txt", rgb), ("depth.txt", depth), ("associated.txt", associated),
                        ("groundtruth.txt", gt)):  # fmt: skip
        (folder / name).write_text("".join(lines))
    K = frames[0].K
    (folder / "calibration.txt").write_text(f"{K[0, 0]} {K[1, 1]} {K[0, 2]} {K[1, 2]}\n")
    return folder


BONN_T_ROS = np.array([[-1, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], np.float64)
BONN_T_M = np.array([
    [1.0157, 0.1828, -0.2389, 0.0113],
    [0.0009, -0.8431, -0.6413, -0.0098],
    [-0.3009, 0.6147, -0.8085, 0.0111],
    [0, 0, 0, 1.0],
])  # fmt: skip
"""``compute_global_transformation.py`` of the Bonn RGB-D Dynamic dataset, as published."""


def bonn_marker_pose(camera: np.ndarray) -> np.ndarray:
    """The marker pose ``groundtruth.txt`` holds for the camera pose ``camera`` (in the
    reference cloud's frame): ``camera = T_ros @ marker @ T_ros @ T_m``, ``T_m`` taken rigid
    (scipy's nearest rotation to its 3x3 block)."""
    T_m = np.eye(4)
    T_m[:3, :3] = Rotation.from_matrix(
        BONN_T_M[:3, :3] / np.cbrt(np.linalg.det(BONN_T_M[:3, :3]))
    ).as_matrix()
    T_m[:3, 3] = BONN_T_M[:3, 3]
    marker: np.ndarray = BONN_T_ROS @ camera @ np.linalg.inv(BONN_T_ROS @ T_m)
    return marker


def bonn(folder: Path, frames: list[Frame]) -> Path:
    return tum(folder, frames, gt_pose=bonn_marker_pose)


def seven_scenes(folder: Path, frames: list[Frame]) -> Path:
    folder.mkdir(parents=True)
    for i, f in enumerate(frames):
        _image(folder / f"frame-{i:06d}.color.png", f.rgb)
        mm = np.round(f.depth_m.astype(np.float64) * 1000.0)
        mm[f.depth_m == 0] = 65535  # the release's "no depth"
        Image.fromarray(mm.astype(np.uint16)).save(folder / f"frame-{i:06d}.depth.png")
        rows = "".join("\t".join(f"{v:.7e}" for v in row) + "\t\n" for row in f.cam_to_world)
        (folder / f"frame-{i:06d}.pose.txt").write_text(rows)
    return folder
