"""ingest stage: robot recordings (MCAP, rosbag2, ROS 1) and dataset folders in, feature
stores out.

- :mod:`ingest.write`: write frames as a recording (the sample world uses it),
- :mod:`ingest.readers`: one reader interface over the container formats,
- :mod:`ingest.decode`: ROS messages to numpy arrays,
- :mod:`ingest.undistort`: lens distortion removed from the images (OpenCV),
- :mod:`ingest.topics`: which topics hold what (auto-detection, overrides),
- :mod:`ingest.tf`: the TF buffer (chains, interpolation),
- :mod:`ingest.conventions`: the camera frame's axes (optical or body), found or given,
- :mod:`ingest.intrinsics`: intrinsics given by hand (``--intrinsics``),
- :mod:`ingest.sync`: stamp matching of depth and labels to colour,
- :mod:`ingest.source`: a recording as a stream of posed :class:`care.frames.Frame`,
- :mod:`ingest.folders`: public datasets' folders (ScanNet, Replica, TUM RGB-D,
  ICL-NUIM/Redwood, Matterport3D, a generic layout) as the same stream,
- :mod:`ingest.pipeline`: ``run_ingest(recording, out, IngestConfig)`` into a store,
- :mod:`ingest.viz`: Rerun logging of an ingest.
"""

from __future__ import annotations

from runtime.lazy import lazy_exports

__all__ = ["ingest"]

__getattr__ = lazy_exports(__name__, {"ingest": "ingest.api"})
