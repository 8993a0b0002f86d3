"""Which synchronised frames ingest keeps: a time range, every Nth frame, enough motion.

Real recordings are long and slow: a robot standing still for a minute gives a thousand
near-identical views that cost encoding time and weigh on the maps' view counts. The
selection runs after synchronisation and posing, on the frames ingest would otherwise keep,
and counts what it skips by reason (``meta.json`` ``counts.skipped``).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame

__all__ = ["FrameSelection", "FrameSelector"]


@dataclass(frozen=True)
class FrameSelection:
    """Which frames to keep; the default keeps every one."""

    start: float | None = None
    """Seconds after the first frame before which frames are skipped."""
    end: float | None = None
    """Seconds after the first frame after which reading stops."""
    every: int = 1
    """Keep every Nth frame of the time range."""
    min_motion: float = 0.0
    """Metres: skip a frame that moved less than this from the last kept one ..."""
    min_rotation: float = 0.0
    """... and turned less than this many degrees (both must be small to skip)."""

    def __post_init__(self) -> None:
        values = {"start": self.start, "end": self.end, "min-motion": self.min_motion,
                  "min-rotation": self.min_rotation}  # fmt: skip
        bad = [k for k, v in values.items() if v is not None and not (math.isfinite(v) and v >= 0)]
        if bad:
            msg = f"--{bad[0]} must be a finite number >= 0, got {values[bad[0]]}"
            raise IngestError(msg)
        if self.every < 1:
            msg = f"--every must be at least 1, got {self.every}"
            raise IngestError(msg)
        if self.start is not None and self.end is not None and self.end < self.start:
            msg = f"--end {self.end} s lies before --start {self.start} s"
            raise IngestError(msg)


@dataclass
class FrameSelector:
    """Applies a :class:`FrameSelection` to a stream of frames, in order."""

    selection: FrameSelection
    skipped: Counter[str] = field(default_factory=Counter)
    done: bool = False
    """Past ``end``: nothing later can be kept, stop reading."""
    _first: int | None = None
    _index: int = -1
    _last: np.ndarray | None = None

    def keep(self, frame: Frame) -> bool:
        sel = self.selection
        if self._first is None:
            self._first = frame.stamp_ns
        t = (frame.stamp_ns - self._first) / 1e9
        if sel.start is not None and t < sel.start:
            self.skipped["before start"] += 1
            return False
        if sel.end is not None and t > sel.end:
            self.done = True
            return False
        self._index += 1
        if self._index % sel.every:
            self.skipped["every"] += 1
            return False
        if self._last is not None and (sel.min_motion > 0 or sel.min_rotation > 0):
            moved = float(np.linalg.norm(frame.cam_to_world[:3, 3] - self._last[:3, 3]))
            rel = self._last[:3, :3].T @ frame.cam_to_world[:3, :3]
            turned = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(rel) - 1) / 2))))
            if moved < sel.min_motion and turned < sel.min_rotation:
                self.skipped["little motion"] += 1
                return False
        self._last = np.asarray(frame.cam_to_world, np.float64)
        return True
