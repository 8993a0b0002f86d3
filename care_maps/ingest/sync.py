"""Match secondary streams (depth, label images) to a primary one (colour) by nearest stamp.

Streaming, with bounded memory: a colour message waits only until every secondary stream
has passed its stamp by ``max_dt`` (so no nearer match can still arrive), then leaves with
the nearest secondary messages within ``max_dt``; secondary messages older than any colour
message can still use are discarded. Messages arrive in log-time order, which may differ
from stamp order by transport latency; ``horizon_ns`` bounds how long anything waits.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["Match", "StampSync", "secondaries_of"]


@dataclass(frozen=True)
class Match:
    """A primary message and its nearest secondary messages (None where optional and unmatched)."""

    stamp_ns: int
    primary: Any
    secondary: dict[str, Any]


class _Stream:
    def __init__(self, required: bool) -> None:
        self.required = required
        self.buffer: deque[tuple[int, Any]] = deque()
        self.latest = -(2**62)

    def nearest(self, t: int, max_dt: int) -> tuple[int, Any] | None:
        best = min(self.buffer, key=lambda item: abs(item[0] - t), default=None)
        return best if best is not None and abs(best[0] - t) <= max_dt else None


class StampSync:
    """Feed messages with :meth:`push`; collect matches from it and from :meth:`finish`.

    ``dropped`` counts unmatched primaries by reason (``no_<stream>``).
    """

    def __init__(
        self, secondaries: Mapping[str, bool], max_dt_ns: int, horizon_ns: int | None = None
    ) -> None:
        self.max_dt = int(max_dt_ns)
        self.horizon = (
            int(horizon_ns) if horizon_ns is not None else max(2 * 10**9, 10 * self.max_dt)
        )
        self.streams = {name: _Stream(required) for name, required in secondaries.items()}
        self.pending: deque[tuple[int, Any]] = deque()
        self.primary_latest = -(2**62)
        self.dropped: Counter[str] = Counter()
        self.nearest_miss: dict[str, int] = {}
        """Smallest |dt| of a secondary message that was further than max_dt (for hints)."""

    def push(self, stream: str | None, stamp_ns: int, item: Any) -> list[Match]:
        """Add a primary (``stream`` None) or secondary message; returns newly resolved matches."""
        t = int(stamp_ns)
        if stream is None:
            self.pending.append((t, item))
            self.primary_latest = max(self.primary_latest, t)
        else:
            s = self.streams[stream]
            s.buffer.append((t, item))
            s.latest = max(s.latest, t)
        return self._resolve(final=False)

    def finish(self) -> list[Match]:
        """Resolve everything still waiting (end of recording)."""
        return self._resolve(final=True)

    def _ready(self, t: int) -> bool:
        if self.primary_latest > t + self.horizon:
            return True
        return all(s.latest > t + self.max_dt for s in self.streams.values())

    def _resolve(self, *, final: bool) -> list[Match]:
        out: list[Match] = []
        while self.pending and (final or self._ready(self.pending[0][0])):
            t, item = self.pending.popleft()
            match = self._match(t, item)
            if match is not None:
                out.append(match)
        self._prune()
        return out

    def _match(self, t: int, item: Any) -> Match | None:
        found: dict[str, Any] = {}
        for name, s in self.streams.items():
            hit = s.nearest(t, self.max_dt)
            if hit is None and s.required:
                self.dropped[f"no_{name}"] += 1
                near = min((abs(st - t) for st, _ in s.buffer), default=None)
                if near is not None:
                    self.nearest_miss[name] = min(self.nearest_miss.get(name, near), near)
                return None
            found[name] = None if hit is None else hit[1]
        return Match(t, item, found)

    def _prune(self) -> None:
        """Drop secondary messages no waiting or future primary can match."""
        oldest_needed = self.pending[0][0] if self.pending else self.primary_latest
        for s in self.streams.values():
            keep_from = max(oldest_needed - self.max_dt, s.latest - self.horizon)
            while s.buffer and s.buffer[0][0] < keep_from:
                s.buffer.popleft()

    def buffered(self) -> int:
        """Messages held right now (primary + secondary), for memory tests."""
        return len(self.pending) + sum(len(s.buffer) for s in self.streams.values())


def secondaries_of(required: Iterable[str], optional: Iterable[str]) -> dict[str, bool]:
    """``{name: required}`` for :class:`StampSync`."""
    return {**dict.fromkeys(optional, False), **dict.fromkeys(required, True)}
