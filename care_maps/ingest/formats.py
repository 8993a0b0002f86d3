"""The container formats of a robot recording, named once: :class:`RecordingFormat`.

The writer (:func:`care_maps.ingest.write.write_recording`), the sample world and ``care sample make
--format`` take these members; only the standard library is imported, so the CLI lists
them on every call.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["RecordingFormat"]


class RecordingFormat(StrEnum):
    """A recording's container format."""

    MCAP = "mcap"
    """A single MCAP file (``.mcap``, ROS 2 messages)."""
    ROS2 = "ros2"
    """A rosbag2 directory (``metadata.yaml`` and its storage files)."""
    ROS1 = "ros1"
    """A ROS 1 bag (``.bag``)."""

    @property
    def suffix(self) -> str:
        """The name suffix of a recording in this format (a rosbag2 directory has none)."""
        return _SUFFIX[self]

    @classmethod
    def choices(cls) -> str:
        """The members as a user reads them: ``mcap, ros2 or ros1``."""
        names = [m.value for m in cls]
        return f"{', '.join(names[:-1])} or {names[-1]}"


_SUFFIX = {RecordingFormat.MCAP: ".mcap", RecordingFormat.ROS2: "", RecordingFormat.ROS1: ".bag"}
