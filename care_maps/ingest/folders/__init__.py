"""Public RGB-D datasets read as they are downloaded: one :class:`~care_maps.ingest.folders.base.FolderLayout`
per :class:`~care_maps.ingest.folders.base.DatasetLayout`, found by the names a folder holds.

- :mod:`care_maps.ingest.folders.base`: the layout interface and its records,
- :mod:`care_maps.ingest.folders.files`: reading a folder's images and text files, one-line errors,
- :mod:`care_maps.ingest.folders.generic`, :mod:`~care_maps.ingest.folders.redwood`, :mod:`~care_maps.ingest.folders.tum`,
  :mod:`~care_maps.ingest.folders.eth3d`, :mod:`~care_maps.ingest.folders.bonn`, :mod:`~care_maps.ingest.folders.sevenscenes`,
  :mod:`~care_maps.ingest.folders.replica`, ...: one module per layout (TUM's variants, ETH3D and Bonn,
  subclass it and mark their folders, so one folder matches one layout),
- :mod:`care_maps.ingest.folders.frames`: a folder as the stream of frames ingest reads
  (:class:`~care_maps.ingest.folders.frames.FolderFrames`, the counterpart of a recording's
  :class:`care_maps.ingest.source.RecordingFrames`).

This package imports only the layouts (light: numpy, PIL, scipy's rotations), so that
:mod:`care_maps.ingest.readers` can tell a dataset folder from a rosbag2 directory cheaply.
"""

from __future__ import annotations

from pathlib import Path

from care_maps.core.errors import IngestError
from care_maps.ingest.folders.base import DatasetLayout, FolderLayout
from care_maps.ingest.folders.bonn import BonnLayout
from care_maps.ingest.folders.eth3d import Eth3dLayout
from care_maps.ingest.folders.generic import GenericLayout
from care_maps.ingest.folders.matterport import MatterportLayout
from care_maps.ingest.folders.redwood import RedwoodLayout
from care_maps.ingest.folders.replica import ReplicaLayout
from care_maps.ingest.folders.scannet import ScanNetLayout
from care_maps.ingest.folders.sevenscenes import SevenScenesLayout
from care_maps.ingest.folders.tum import TumLayout

__all__ = ["LAYOUTS", "DatasetLayout", "FolderLayout", "detect_layout", "is_dataset_folder"]

# -- the registry ---------------------------------------------------------------------------
# One entry per DatasetLayout member with a reader; a layout module adds its class here.
LAYOUTS: dict[DatasetLayout, type[FolderLayout]] = {
    DatasetLayout.SCANNET: ScanNetLayout,
    DatasetLayout.REPLICA: ReplicaLayout,
    DatasetLayout.TUM: TumLayout,
    DatasetLayout.ETH3D: Eth3dLayout,
    DatasetLayout.BONN: BonnLayout,
    DatasetLayout.REDWOOD: RedwoodLayout,
    DatasetLayout.MATTERPORT: MatterportLayout,
    DatasetLayout.SEVEN_SCENES: SevenScenesLayout,
    DatasetLayout.GENERIC: GenericLayout,
}
"""Layout class by :class:`DatasetLayout` (what ``--format`` names)."""
# -------------------------------------------------------------------------------------------


def detect_layout(path: Path) -> DatasetLayout | None:
    """The layout of the folder ``path`` by the names it holds (nothing decoded); None when it
    is not a folder, or none matches. Two matching layouts are one error that names both and
    the option that picks one: reading it as either could be wrong."""
    path = Path(path)
    if not path.is_dir():
        return None
    found = [kind for kind, cls in LAYOUTS.items() if cls.detect(path)]
    if len(found) > 1:
        names = ", ".join(str(kind) for kind in found)
        msg = f"{path}: the folder matches more than one dataset layout ({names}); pass --format {found[0]} (or another of them) to say how to read it."
        raise IngestError(msg)
    return found[0] if found else None


def is_dataset_folder(path: Path) -> bool:
    """Whether ``path`` is a folder of some dataset layout (a folder matching two is one too:
    reading it says which to pick)."""
    try:
        return detect_layout(path) is not None
    except IngestError:
        return True
