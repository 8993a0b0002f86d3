"""A recording written as several files is one recording.

``rosbag record --split`` writes ``run_0.bag``, ``run_1.bag``, ...; MCAP recorders roll
over to a new file by size or duration. :func:`recording_parts` checks such a list (each a
recording file that exists, named once, all of one kind) and :class:`SplitReader` reads the
files as one recording behind the :class:`care_maps.ingest.readers.RecordingReader`
interface: the files ordered by their first message's log time (not by name), topics merged
(counts summed), messages merged into one log-time order across the files. Overlaps and gaps
between files are then what they would be inside one file: TF read in the first pass holds
every file's transforms (a static chain from whichever file holds it, a moving transform
interpolated across a file boundary), and two files that disagree at one stamp are refused
as one file would be.

Files of another recording are refused in one line naming the file: a topic with another
type than in the other files, other camera image topics (:meth:`SplitReader.__enter__`), or
colour images in another frame (:meth:`SplitReader.check_frames`).
"""

from __future__ import annotations

import heapq
import operator
from collections.abc import Collection, Iterator, Sequence
from contextlib import ExitStack
from enum import StrEnum
from pathlib import Path
from typing import Any

from care_maps.core.errors import IngestError
from care_maps.ingest.readers import ClosedOnExit, RecordingReader, TopicInfo, open_reader
from care_maps.ingest.topics import IMAGE_TYPES

__all__ = [
    "PartKind",
    "Recording",
    "SplitReader",
    "open_recording",
    "part_kind",
    "parts_label",
    "recording_parts",
]

Recording = Path | Sequence[Path]
"""What ingest reads: one path (a file, a rosbag2 directory, a dataset folder), or the
files of one recording written in several."""


class PartKind(StrEnum):
    """The kinds of file a recording can be split into; the parts of one are all of one."""

    ROS1 = "a ROS 1 bag"
    MCAP = "an MCAP file"
    ROSBAG2 = "a rosbag2 recording"


_KINDS = {".bag": PartKind.ROS1, ".mcap": PartKind.MCAP, ".db3": PartKind.ROSBAG2}


def part_kind(path: Path) -> PartKind | None:
    """The kind of recording file ``path`` is by its suffix (a rosbag2 directory by its
    ``metadata.yaml``); None for anything else (a dataset folder, another file)."""
    path = Path(path)
    if path.is_dir():
        return PartKind.ROSBAG2 if (path / "metadata.yaml").is_file() else None
    return _KINDS.get(path.suffix.lower())


def recording_parts(recording: Recording) -> tuple[Path, ...]:
    """The files of ``recording`` as given: one path as it is (whatever it is: the readers
    judge it), several checked to be one recording's files: each exists, is a recording file
    (not a dataset folder), is named once, and all are of one kind."""
    if isinstance(recording, (str, Path)):
        return (Path(recording),)
    parts = tuple(Path(p) for p in recording)
    if not parts:
        msg = "no recording given; pass a recording, or the files of one recording written in several."
        raise IngestError(msg)
    if len(parts) == 1:
        return parts
    seen: dict[Path, Path] = {}
    kinds: dict[PartKind, Path] = {}
    for part in parts:
        if not part.exists():
            msg = (
                f"{part}: no such file or directory; check the path of this file of the recording."
            )
            raise IngestError(msg)
        kind = part_kind(part)
        if kind is None:
            msg = f"{part}: not a recording file (.bag, .mcap, .db3 or a rosbag2 directory); a recording in several files is read from its files only: pass a dataset folder alone."
            raise IngestError(msg)
        same = seen.get(part.resolve())
        if same is not None:
            msg = f"{part}: given twice (also as {same}); pass each file of the recording once."
            raise IngestError(msg)
        seen[part.resolve()] = part
        other = next(iter(kinds.items()), None)
        if other is not None and other[0] is not kind:
            msg = f"{part}: is {kind} but {other[1]} is {other[0]}; the files of one recording are all of one kind: ingest each recording apart."
            raise IngestError(msg)
        kinds.setdefault(kind, part)
    return parts


def parts_label(parts: Sequence[Path]) -> str:
    """How messages name a recording: its path, or its files' (the first in full, the
    others by name; ``first … last (N files)`` for more than four)."""
    if len(parts) == 1:
        return str(parts[0])
    if len(parts) > 4:
        return f"{parts[0]} … {parts[-1].name} ({len(parts)} files)"
    return ", ".join([str(parts[0]), *(p.name for p in parts[1:])])


def open_recording(recording: Recording) -> RecordingReader:
    """The reader of ``recording`` (not yet entered): :func:`open_reader`'s for one path,
    a :class:`SplitReader` for several files."""
    parts = recording_parts(recording)
    if len(parts) == 1:
        return open_reader(parts[0])
    return SplitReader(parts)


def _image_topics(topics: dict[str, TopicInfo]) -> set[str]:
    return {name for name, info in topics.items() if info.msgtype in IMAGE_TYPES}


class SplitReader(ClosedOnExit):
    """The files of one recording read as one (a :class:`RecordingReader`): entered, its
    :attr:`parts` are in order of their first message's log time (ties by name)."""

    def __init__(self, parts: Sequence[Path]) -> None:
        self.parts = recording_parts(parts)
        self.path = self.parts[0]
        """The first file (by time, once entered)."""
        self._readers: list[RecordingReader] = []
        self._stack: ExitStack | None = None

    def __enter__(self) -> SplitReader:
        with ExitStack() as stack:
            opened = [(stack.enter_context(open_reader(p)), p) for p in self.parts]
            timed = [(reader.first_time(), str(path), reader) for reader, path in opened]
            # files without messages last: they add topics, no message
            timed.sort(key=lambda x: (x[0] is None, x[0] or 0, x[1]))
            self._readers = [reader for *_, reader in timed]
            self.parts = tuple(reader.path for reader in self._readers)
            self.path = self.parts[0]
            self._check_topics()
            self._stack = stack.pop_all()
        return self

    def close(self) -> None:
        """Close every file."""
        stack, self._stack = self._stack, None
        self._readers = []
        if stack is not None:
            stack.close()

    def _check_topics(self) -> None:
        """Refuse a file that cannot be of this recording: a topic typed otherwise than in
        an earlier file, or other camera image topics than the files before it."""
        types: dict[str, tuple[str, Path]] = {}
        images: tuple[set[str], Path] | None = None
        for reader in self._readers:
            topics = reader.topics()
            for name, info in topics.items():
                first = types.setdefault(name, (info.msgtype, reader.path))
                if first[0] != info.msgtype:
                    msg = f"{reader.path}: topic {name} is {info.msgtype} here but {first[0]} in {first[1]}; not a file of the same recording: leave it out."
                    raise IngestError(msg)
            own = _image_topics(topics)
            if not own:  # TF or camera info alone: nothing to compare
                continue
            if images is None:
                images = (own, reader.path)
            elif own != images[0]:
                msg = f"{reader.path}: image topics {', '.join(sorted(own))}, but {', '.join(sorted(images[0]))} in {images[1]}; not a file of the same recording (its files record the same cameras): leave it out."
                raise IngestError(msg)

    def check_frames(self, rgb: str) -> None:
        """Refuse a file whose colour images on ``rgb`` are in another frame than the first
        file's (``header.frame_id`` of each file's first image): another camera's recording."""
        first: tuple[str, Path] | None = None
        for reader in self._readers:
            if rgb not in reader.topics():
                continue
            msg_ = next(iter(reader.messages([rgb])), None)
            if msg_ is None:
                continue
            frame = str(msg_[2].header.frame_id).lstrip("/")
            if first is None:
                first = (frame, reader.path)
            elif frame != first[0]:
                msg = f"{reader.path}: colour images on {rgb} are in frame {frame!r}, but in {first[0]!r} in {first[1]}; not a file of the same recording: leave it out."
                raise IngestError(msg)

    def topics(self) -> dict[str, TopicInfo]:
        """Topics by name over all files, their counts summed."""
        merged: dict[str, TopicInfo] = {}
        for reader in self._readers:
            for name, info in reader.topics().items():
                before = merged.get(name)
                count = info.count + (before.count if before else 0)
                merged[name] = TopicInfo(name, info.msgtype, count)
        return merged

    def messages(self, topics: Collection[str] = ()) -> Iterator[tuple[str, int, Any]]:
        """Every file's messages merged in log-time order (at one time, the earlier file's
        first)."""
        streams = [reader.messages(topics) for reader in self._readers]
        return heapq.merge(*streams, key=operator.itemgetter(1))

    def first_time(self) -> int | None:
        """The first file's first message's log time."""
        return self._readers[0].first_time() if self._readers else None
