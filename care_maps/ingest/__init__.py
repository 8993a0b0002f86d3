"""ingest stage: robot recordings (MCAP, rosbag2, ROS 1) and dataset folders in, feature
stores out.

- :mod:`care_maps.ingest.write`: write frames as a recording (the sample world uses it),
- :mod:`care_maps.ingest.readers`: one reader interface over the container formats,
- :mod:`care_maps.ingest.parts`: a recording in several files (split bags, MCAP) read as one,
- :mod:`care_maps.ingest.decode`: ROS messages to numpy arrays,
- :mod:`care_maps.ingest.undistort`: lens distortion removed from the images (OpenCV),
- :mod:`care_maps.ingest.topics`: which topics hold what (auto-detection, overrides),
- :mod:`care_maps.ingest.tf`: the TF buffer (chains, interpolation),
- :mod:`care_maps.ingest.conventions`: the camera frame's axes (optical or body), found or given,
- :mod:`care_maps.ingest.intrinsics`: intrinsics given by hand (``--intrinsics``),
- :mod:`care_maps.ingest.sync`: stamp matching of depth and labels to colour,
- :mod:`care_maps.ingest.source`: a recording as a stream of posed :class:`care_maps.core.frames.Frame`,
- :mod:`care_maps.ingest.folders`: public datasets' folders (ScanNet, Replica, TUM RGB-D,
  ICL-NUIM/Redwood, Matterport3D, a generic layout) as the same stream,
- :mod:`care_maps.ingest.pipeline`: ``run_ingest(recording, out, IngestConfig)`` into a store,
- :mod:`care_maps.ingest.viz`: Rerun logging of an ingest.
"""

from __future__ import annotations

from care_maps.runtime.lazy import lazy_exports

__all__ = ["ingest"]

__getattr__ = lazy_exports(__name__, {"ingest": "care_maps.ingest.api"})
