"""Ground truth of a sample-world recording, in the project's one ground-truth model.

The model (:class:`truth.model.GroundTruth`) and the native files beside each recording
(``scene_000.mcap`` -> ``scene_000.gt.parquet`` + ``scene_000.gt.json``, documented in
:mod:`truth.formats.native`) live in the ``truth`` package, which the evaluation reads too;
this module keeps the names the sample world and its callers have always imported.
"""

from __future__ import annotations

from truth.formats.native import GT_SCHEMA_VERSION, gt_paths
from truth.model import INSTANCE_COLUMNS, GroundTruth, Room, instances_table

__all__ = [
    "GT_SCHEMA_VERSION",
    "INSTANCE_COLUMNS",
    "GroundTruth",
    "Room",
    "gt_paths",
    "instances_table",
]
