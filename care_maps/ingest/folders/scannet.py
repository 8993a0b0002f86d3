"""ScanNet (v2) scenes as ScanNet's SensReader exports them from ``<scene>.sens``
(``reader.py --export_depth_images --export_color_images --export_poses --export_intrinsics``,
github.com/ScanNet/ScanNet ``SensReader/python/SensorData.py``).

```
scene0000_00/                       the export, or the downloaded scene folder holding it
  color/0.jpg, 1.jpg, ...           colour, 1296x968 JPEG; the name is the .sens frame index
  depth/0.png, ...                  16-bit PNG depth in millimetres (the .sens depth shift,
                                    1000), 640x480
  pose/0.txt, ...                   camera-to-world 4x4, four rows of four; ``-inf`` (or
                                    ``nan``) in every entry where the tracking was lost
  intrinsic/intrinsic_color.txt     4x4 pinhole matrix of the colour camera
  intrinsic/intrinsic_depth.txt     4x4 pinhole matrix of the depth camera
  intrinsic/extrinsic_*.txt         not used (below)
  scene0000_00_vh_clean_2.ply, ...  the scan's ground truth, when the export lies in the
                                    downloaded scene folder (read by :mod:`care_maps.truth.formats.scannet`)
```

- Poses: camera-to-world in the scan's frame (the frame of ``_vh_clean_2.ply``; the
  ``axisAlignment`` of ``<scene>.txt`` is not applied), camera x right, y down, z forward:
  our optical frame, as it is. A colour image whose pose is not finite, or that has no pose
  file, is left out and counted (``no_pose``); one without its depth image too (``no_depth``).
- Registration: colour and depth are taken from one viewpoint: ScanNet's maintainers say
  the two "are already aligned, so no extrinsic matrices should be applied" (threads 2 and
  92 of github.com/ScanNet/ScanNet), so ``extrinsic_*.txt`` and the
  ``colorToDepthExtrinsics`` of ``<scene>.txt`` are ignored. The two calibrations differ by
  about 1% in focal length after scaling (fx 1170.2 at 1296 px against 571.6 at 640 px in
  scene0709_00), so the colour image is resampled into the depth camera through both
  intrinsics, ``K_colour @ inv(K_depth)`` per pixel, rather than resized to the depth size
  as OpenMask3D and ConceptGraphs do. Views come out at the depth resolution with the depth
  intrinsics: depth, whose values must not be blended across edges, is never interpolated.
  Depth pixels whose ray leaves the colour image get depth 0, counted in the store's
  ``counts.lost_pixels.outside_colour_view`` (about a sixth of the valid depth when the two
  cameras' fields of view differ as the living-room test's do).
- ``--intrinsics`` replaces the depth camera (the camera of the views as returned); the
  colour camera stays ``intrinsic_color.txt``'s.
- Timing: the export keeps no times. A view's stamp is its frame index (the file name) at
  30 Hz, the rate of the Structure sensor ScanNet was captured with, so frames exported with
  a ``frame_skip`` keep their true spacing.
- Labels: none per image (the 2D label zips are not read); ground truth is the scan's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.ingest.folders.base import (
    DatasetLayout,
    FolderLayout,
    FolderOptions,
    FolderView,
    nominal_stamp_ns,
)
from care_maps.ingest.folders.files import (
    DEPTH_MILLIMETRES,
    Intrinsics,
    numbers,
    read_colour,
    read_depth,
    table,
)

__all__ = ["OUTSIDE_COLOUR_VIEW", "ScanNetLayout", "colour_in_depth_camera"]

COLOUR_FOLDER = "color"
DEPTH_FOLDER = "depth"
POSE_FOLDER = "pose"
INTRINSIC_FOLDER = "intrinsic"
COLOUR_INTRINSIC = "intrinsic_color.txt"
DEPTH_INTRINSIC = "intrinsic_depth.txt"
COLOUR_SUFFIX = ".jpg"
DEPTH_SUFFIX = ".png"
POSE_SUFFIX = ".txt"
CENTRE_TOLERANCE = 0.1
"""Largest distance of a principal point from its image's centre, as a share of the image's
side: farther means the image is not the size its intrinsics were calibrated at."""
OUTSIDE_COLOUR_VIEW = "outside_colour_view"
"""The :attr:`ingest.source.ReadStats.lost_pixels` reason of valid depth pixels whose ray
leaves the colour image (zeroed: no colour to give them)."""
_HOMOGENEOUS_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_EXPORT_HINT = "export the scene with ScanNet's SensReader (reader.py --export_depth_images --export_color_images --export_poses --export_intrinsics)"


def _frame_files(folder: Path, suffix: str) -> dict[int, Path]:
    """The folder's ``<index><suffix>`` files by frame index (other names are not frames)."""
    if not folder.is_dir():
        return {}
    return {int(p.stem): p for p in folder.iterdir() if p.suffix == suffix and p.stem.isdigit()}


def _matrix(path: Path, what: str) -> np.ndarray:
    """A 4x4 matrix file as SensReader writes it (four rows of four numbers)."""
    rows = table(path, 4, what)
    if len(rows) != 4:
        msg = f"{path}: {len(rows)} rows, expected 4 rows of 4 numbers ({what}); {_EXPORT_HINT}."
        raise IngestError(msg)
    return np.stack([numbers(fields, path, line) for line, fields in rows])


def _camera(path: Path, source: str) -> Intrinsics:
    matrix = _matrix(path, "a 4x4 pinhole matrix: fx 0 cx 0 / 0 fy cy 0 / 0 0 1 0 / 0 0 0 1")
    return Intrinsics(matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], source=source)


def _check_centred(camera: Intrinsics, image: Path, width: int, height: int) -> None:
    """Refuse an image whose principal point is far from its centre: it was resized or cropped
    after the export, and its intrinsics do not describe it."""
    cx, cy = camera.K[0, 2], camera.K[1, 2]
    if abs(2 * cx + 1 - width) > CENTRE_TOLERANCE * width or abs(2 * cy + 1 - height) > (
        CENTRE_TOLERANCE * height
    ):
        msg = f"{image}: {width}x{height} image, but {camera.source} (cx {cx:g}, cy {cy:g}) is for about {2 * cx + 1:.0f}x{2 * cy + 1:.0f}; the image was resized after the export: {_EXPORT_HINT}."
        raise IngestError(msg)


def colour_in_depth_camera(
    rgb: np.ndarray, K_colour: np.ndarray, K_depth: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """The colour image seen by the depth camera of the same viewpoint: ``(rgb, inside)``,
    (height, width, 3) uint8 and the (height, width) mask of pixels whose ray falls in the
    colour image (the others are black).

    Depth pixel (u, v) (integer pixel centres, as ``K`` states them) sees colour pixel
    ``(s_x u + o_x, s_y v + o_y)`` with ``s = f_colour / f_depth`` and
    ``o = c_colour - s c_depth``. A colour image at least twice the depth size is first
    averaged over ``k x k`` blocks (so the shrink does not alias), then sampled bilinearly."""
    scale = np.array([K_colour[0, 0] / K_depth[0, 0], K_colour[1, 1] / K_depth[1, 1]])
    offset = K_colour[:2, 2] - scale * K_depth[:2, 2]
    colour_h, colour_w = rgb.shape[:2]
    u = scale[0] * np.arange(width) + offset[0]
    v = scale[1] * np.arange(height) + offset[1]
    rows = (v >= -0.5) & (v <= colour_h - 0.5)
    columns = (u >= -0.5) & (u <= colour_w - 0.5)
    inside = rows[:, None] & columns[None, :]
    from PIL import Image  # at first image: not at the CLI's start

    image = Image.fromarray(rgb)
    block = max(1, int(min(scale)))
    if block > 1:
        image = image.reduce(block)  # block j's centre is colour pixel j*block + (block-1)/2
        scale, offset = scale / block, (offset - (block - 1) / 2) / block
    # PIL samples output pixel x at input a * (x + 0.5) + c in edge coordinates (pixel i spans
    # [i, i + 1)): the pixel-centre map above shifted by half a pixel on both sides
    c = offset + 0.5 - 0.5 * scale
    out = image.transform(
        (width, height),
        Image.Transform.AFFINE,
        (scale[0], 0.0, c[0], 0.0, scale[1], c[1]),
        resample=Image.Resampling.BILINEAR,
    )
    return np.asarray(out), inside


class ScanNetLayout(FolderLayout):
    """A ScanNet scene exported by SensReader (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.SCANNET
    world_frame: ClassVar[str] = "scannet_world"

    @classmethod
    def detect(cls, path: Path) -> bool:
        path = Path(path)
        return all((path / name).is_dir() for name in (COLOUR_FOLDER, DEPTH_FOLDER, POSE_FOLDER))

    def __init__(self, path: Path, *, max_dt: float, options: FolderOptions | None = None) -> None:
        super().__init__(path, max_dt=max_dt, options=options)
        self._cameras: tuple[Intrinsics, Intrinsics] | None = None

    def _intrinsics(self) -> tuple[Intrinsics, Intrinsics]:
        """``(colour, depth)`` cameras from ``intrinsic/``."""
        if self._cameras is None:
            folder = self.path / INTRINSIC_FOLDER
            names = (COLOUR_INTRINSIC, DEPTH_INTRINSIC)
            missing = [name for name in names if not (folder / name).is_file()]
            if missing:
                msg = f"{folder / missing[0]}: missing; the colour and depth cameras are needed to register them: {_EXPORT_HINT}."
                raise IngestError(msg)
            colour, depth = (_camera(folder / n, f"{INTRINSIC_FOLDER}/{n}") for n in names)
            self._cameras = (colour, self.camera(depth)[0])
        return self._cameras

    def _pose(self, path: Path) -> np.ndarray:
        """The pose of one ``pose/<i>.txt``, non-finite where the tracking was lost."""
        matrix = _matrix(path, "a camera-to-world 4x4, four rows of four numbers")
        if np.isfinite(matrix).all() and not np.allclose(matrix[3], _HOMOGENEOUS_ROW):
            msg = f"{path}: last row {matrix[3].tolist()} is not 0 0 0 1, so the matrix is not a pose; {_EXPORT_HINT}."
            raise IngestError(msg)
        return self.file_pose(matrix)

    def views(self) -> list[FolderView]:
        self._intrinsics()
        self.dropped.clear()
        colour = _frame_files(self.path / COLOUR_FOLDER, COLOUR_SUFFIX)
        depth = _frame_files(self.path / DEPTH_FOLDER, DEPTH_SUFFIX)
        poses = _frame_files(self.path / POSE_FOLDER, POSE_SUFFIX)
        views = []
        for index in sorted(colour):
            pose = self._pose(poses[index]) if index in poses else None
            if pose is None or not np.isfinite(pose).all():
                self.dropped["no_pose"] += 1
            elif index not in depth:
                self.dropped["no_depth"] += 1
            else:
                views.append(FolderView(nominal_stamp_ns(index), colour[index], depth[index], pose))
        if not views:
            found = f"{len(colour)} colour, {len(depth)} depth images and {len(poses)} poses"
            msg = f"{self.path}: no view has a colour image, its depth image and a finite pose ({found} in {COLOUR_FOLDER}/, {DEPTH_FOLDER}/, {POSE_FOLDER}/); {_EXPORT_HINT}."
            raise IngestError(msg)
        return views

    def load(self, view: FolderView) -> Frame:
        colour_camera, depth_camera = self._intrinsics()
        depth = read_depth(view.depth, self.scale(DEPTH_MILLIMETRES))
        rgb = read_colour(view.colour)
        _check_centred(depth_camera, view.depth, depth.shape[1], depth.shape[0])
        _check_centred(colour_camera, view.colour, rgb.shape[1], rgb.shape[0])
        rgb, inside = colour_in_depth_camera(
            rgb, colour_camera.K, depth_camera.K, depth.shape[1], depth.shape[0]
        )
        self.lost_pixels[OUTSIDE_COLOUR_VIEW] += int(np.count_nonzero(depth[~inside]))
        depth[~inside] = 0.0
        return Frame(view.stamp_ns, rgb, depth, depth_camera.K.copy(), view.cam_to_world)

    def describe(self) -> dict[str, Any]:
        colour, depth = self._intrinsics()
        return {
            "colour": f"{COLOUR_FOLDER}/<i>{COLOUR_SUFFIX}", "depth": f"{DEPTH_FOLDER}/<i>{DEPTH_SUFFIX}",
            "poses": f"{POSE_FOLDER}/<i>{POSE_SUFFIX}", "colour_intrinsics": colour.as_json(),
            "intrinsics": depth.as_json(), "depth_scale": self.scale(DEPTH_MILLIMETRES),
            "registration": "colour resampled into the depth camera",
        }  # fmt: skip
