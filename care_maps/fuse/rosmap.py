"""The grid's obstacle layer as a ROS occupancy map: ``map.pgm`` + ``map.yaml``.

Navigation stacks read maps in the ``map_server`` format (ROS 1 ``map_server``, ROS 2
``nav2_map_server``): an 8-bit greyscale image and a YAML file with the resolution, the pose of
the image's *lower-left* pixel in the map frame (``origin: [x, y, yaw]``) and the thresholds
that turn grey levels into occupied / free / unknown. We write what ``map_saver`` writes in
``trinary`` mode: occupied = 0 (black), free = 254 (white), unknown = 205 (grey), with ROS 1
``map_saver``'s thresholds, so ``map_server`` and ``nav2_map_server`` read back exactly the
three classes:

- occupied: a cell whose highest point stands above ``obstacle_height`` (the grid's
  ``obstacle`` column);
- free: a cell the depth saw, with nothing above ``obstacle_height`` (floor);
- unknown: a cell no depth pixel fell into.

Row 0 of the image is the largest y (north up), so the lower-left pixel is cell (0, 0) of the
grid and ``origin`` is the grid's origin.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from care_maps.core.outputs import write_atomic

__all__ = [
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "RosMapThresholds",
    "occupancy_image",
    "write_ros_map",
]

OCCUPIED, FREE, UNKNOWN = 0, 254, 205
"""Grey levels ``map_saver`` writes in trinary mode."""


@dataclass(frozen=True)
class RosMapThresholds:
    """How ``map_server`` turns grey levels into occupancy (``negate: 0``)."""

    occupied_thresh: float = 0.65
    """A pixel with (255 - value) / 255 above this is occupied."""
    free_thresh: float = 0.196
    """A pixel with (255 - value) / 255 below this is free; in between is unknown. ROS 1's
    ``map_saver`` value: the unknown grey 205 reads as 50/255 = 0.19608, so with nav2's
    default of 0.25 it would load as *free*; 0.196 keeps it unknown in both loaders."""


def occupancy_image(
    ix: np.ndarray, iy: np.ndarray, obstacle: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """(ny, nx) uint8 trinary image of the occupied cells (north up, row 0 = largest y)."""
    nx, ny = shape
    image = np.full((ny, nx), UNKNOWN, dtype=np.uint8)
    image[ny - 1 - np.asarray(iy), np.asarray(ix)] = np.where(
        np.asarray(obstacle, dtype=bool), OCCUPIED, FREE
    )
    return image


def write_ros_map(
    image: np.ndarray,
    cell_size: float,
    origin: tuple[float, float],
    directory: Path,
    *,
    stem: str = "map",
    thresholds: RosMapThresholds | None = None,
) -> tuple[Path, Path]:
    """Write ``<stem>.pgm`` (binary P5) and ``<stem>.yaml`` beside each other; returns both.

    ``origin`` is the map-frame (x, y) of the lower-left corner of the image's bottom-left
    pixel; the YAML names the image relative to itself, as ``map_saver`` does.
    """
    thresholds = thresholds or RosMapThresholds()
    directory = Path(directory)
    pgm, spec = directory / f"{stem}.pgm", directory / f"{stem}.yaml"
    write_atomic(pgm, lambda p: Image.fromarray(image, mode="L").save(p, format="PPM"))
    fields = {
        "image": pgm.name,
        "mode": "trinary",
        "resolution": float(cell_size),
        "origin": [float(origin[0]), float(origin[1]), 0.0],
        "negate": 0,
        "occupied_thresh": thresholds.occupied_thresh,
        "free_thresh": thresholds.free_thresh,
    }
    write_atomic(
        spec,
        lambda p: p.write_text(yaml.safe_dump(fields, sort_keys=False, default_flow_style=None)),
    )
    return pgm, spec
