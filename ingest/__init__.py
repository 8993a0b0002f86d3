"""ingest stage: robot recordings (MCAP, rosbag2, ROS 1) in, feature stores out.

- :mod:`ingest.write`: write frames as a recording (the sample world uses it),
- :mod:`ingest.readers`: one reader interface over the container formats,
- :mod:`ingest.decode`: ROS messages to numpy arrays,
- :mod:`ingest.topics`: which topics hold what (auto-detection, overrides),
- :mod:`ingest.tf`: the TF buffer (chains, interpolation),
- :mod:`ingest.sync`: stamp matching of depth and labels to colour,
- :mod:`ingest.source`: a recording as a stream of posed :class:`care.frames.Frame`,
- :mod:`ingest.pipeline`: ``run_ingest(IngestConfig)`` into a store,
- :mod:`ingest.viz`: Rerun logging of an ingest.
"""

from __future__ import annotations

from typing import Any

__all__ = ["ingest"]


def __getattr__(name: str) -> Any:
    """The stage function(s) (``ingest``), imported on first use: the
    package's light modules stay light to import."""
    if name in __all__:
        from ingest.api import ingest  # noqa: F401

        return locals()[name]
    msg = f"module {__name__!r} has no attribute {name!r}"
    raise AttributeError(msg)
