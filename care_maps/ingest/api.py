"""The ingest stage as one function: a recording in, a feature store out."""

from __future__ import annotations

from pathlib import Path

from care_maps.core.encoders import Encoder
from care_maps.core.store import Store
from care_maps.ingest.parts import Recording
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.runs import RunOptions
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution

__all__ = ["ingest"]


def ingest(
    recording: Recording,
    out: Path,
    config: IngestConfig | None = None,
    *,
    run: Execution = DEFAULT_EXECUTION,
    encoder: Encoder | None = None,
    placement: RunOptions | None = None,
) -> Store:
    """Ingest ``recording`` into the store ``out`` and open it.

    ``recording``: a recording (MCAP file, rosbag2 directory, ROS 1 bag), a dataset folder,
    or a list of one recording's files (split bags or MCAP files), read as one in time order.

    Everything the store depends on is in the arguments: the recording, and what the store
    is made from (``config``, default :class:`IngestConfig`); ``run`` says how the job runs
    (``overwrite`` rebuilds a current store, ``progress`` shows a bar). An up-to-date store
    (same recording content and options) is returned without any work, or a model loaded.
    ``encoder``: an already built encoder instance. ``placement``: add the recording to
    ``out`` as one more exploration run of the same place (:mod:`care_maps.ingest.runs`).
    """
    return Store(run_ingest(recording, out, config, run=run, encoder=encoder, placement=placement))
