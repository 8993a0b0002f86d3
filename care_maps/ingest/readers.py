"""One reader interface over MCAP files, rosbag2 directories and ROS 1 bags.

A reader is a context manager that lists its topics and lazily yields decoded
``(topic, log_time_ns, message)`` triples; messages are rosbags message objects (ROS 1 or
ROS 2 field names, see :mod:`care_maps.ingest.decode`). :func:`open_reader` picks the reader from the
path's suffix or directory layout (``READERS``), like rosbags' own storage-plugin table.

All three go through ``rosbags``; ``mcap`` would do for MCAP as well, but one deserialiser
keeps the decoded message types identical across formats. rosbags 0.11.9 reads zero
messages from some rosbag2 directories whose ``metadata.yaml`` lists topics in another
order than their storage file (ros2/rosbag2's own ``talker`` fixtures); we detect that
(metadata counts messages, none come out) and read the storage files directly, which
works, and raise rather than return an empty recording if that fails too.
"""

from __future__ import annotations

import itertools
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

from care_maps.core.errors import IngestError
from care_maps.ingest.typestores import register_msgdef, ros1_typestore, ros2_typestore

__all__ = [
    "READERS",
    "ClosedOnExit",
    "RecordingReader",
    "Ros2Reader",
    "Rosbag1Reader",
    "TopicInfo",
    "is_recording",
    "open_reader",
    "recordings_in",
]


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a recording: name, ROS 2 style type name (``pkg/msg/Type``), message count."""

    name: str
    msgtype: str
    count: int


class RecordingReader(Protocol):
    """What ingest needs from any container format."""

    path: Path

    def __enter__(self) -> RecordingReader: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None: ...

    def topics(self) -> dict[str, TopicInfo]:
        """Topics by name."""
        ...

    def messages(self, topics: Collection[str] = ()) -> Iterator[tuple[str, int, Any]]:
        """Decoded ``(topic, log_time_ns, message)`` in log-time order; all topics if empty."""
        ...

    def first_time(self) -> int | None:
        """Log time (ns) of the first message, none decoded; None for an empty recording."""
        ...


class ClosedOnExit:
    """A reader (or frames over one) left by ``with`` is closed, whatever happened inside:
    the one ``__exit__`` of every reader and frames class, each defining :meth:`close`."""

    def close(self) -> None:
        """Release what the reader holds open."""

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


_CORRUPT_HINT = "the file is truncated or corrupt; re-copy or re-record it"


class _RosbagsReader(ClosedOnExit):
    """Shared part of the rosbags-backed readers: typestore extension and lazy decoding."""

    kind = ""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._reader: Any = None
        self._decodable: dict[str, bool] = {}

    def _open_backend(self) -> Any:
        raise NotImplementedError

    def _deserialize(self, raw: bytes, msgtype: str) -> Any:
        raise NotImplementedError

    @property
    def _store(self) -> Any:
        raise NotImplementedError

    def __enter__(self) -> _RosbagsReader:
        if not self.path.exists():
            msg = f"{self.path}: no such file or directory; check the recording path."
            raise IngestError(msg)
        try:
            self._reader = self._open_backend()
        except IngestError:
            raise
        except Exception as err:
            msg = f"{self.path}: cannot open as {self.kind} ({type(err).__name__}: {err}); {_CORRUPT_HINT}, or pass a file of a supported format (.mcap, rosbag2 directory, .bag)."
            raise IngestError(msg) from err
        for conn in self._connections():
            self._learn(conn)
        return self

    def close(self) -> None:
        if self._reader is not None:
            reader, self._reader = self._reader, None
            try:
                reader.close()
            except Exception:  # closing after a read error: the read error is what matters
                return

    def _connections(self) -> list[Any]:
        return list(self._reader.connections)

    def _learn(self, conn: Any) -> None:
        """Register the recording's own definition of types the typestore lacks."""
        if conn.msgtype in self._decodable:
            return
        ok = conn.msgtype in self._store.fielddefs
        if not ok and conn.msgdef is not None and conn.msgdef.data:
            fmt = "idl" if conn.msgdef.format.name == "IDL" else "msg"
            ok = register_msgdef(self._store, conn.msgtype, conn.msgdef.data, fmt)
        self._decodable[conn.msgtype] = ok

    def topics(self) -> dict[str, TopicInfo]:
        counts: dict[str, list[Any]] = {}
        for conn in self._connections():
            counts.setdefault(conn.topic, []).append(conn)
        return {
            name: TopicInfo(name, conns[0].msgtype, sum(max(c.msgcount, 0) for c in conns))
            for name, conns in counts.items()
        }

    def _raw(self, conns: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        return self._reader.messages(conns)

    def first_time(self) -> int | None:
        conns = self._connections()
        if not conns:
            return None
        try:
            # each storage file yields in log-time order: its first message is its earliest
            times = [int(t) for _, t, _ in self._firsts(conns)]
        except Exception as err:
            msg = f"{self.path}: error while reading messages ({type(err).__name__}: {err}); {_CORRUPT_HINT}."
            raise IngestError(msg) from err
        return min(times, default=None)

    def _firsts(self, conns: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        """The first raw message of the recording (of each storage file where they are read
        one by one)."""
        yield from itertools.islice(self._raw(conns), 1)

    def messages(self, topics: Collection[str] = ()) -> Iterator[tuple[str, int, Any]]:
        wanted = set(topics)
        conns = [c for c in self._connections() if not wanted or c.topic in wanted]
        if not conns:
            return
        for conn in conns:
            if not self._decodable.get(conn.msgtype, False):
                msg = f"{self.path}: topic {conn.topic} has type {conn.msgtype} whose definition is neither known nor stored in the recording; pick another topic."
                raise IngestError(msg)
        try:
            for conn, t, raw in self._raw(conns):
                yield conn.topic, int(t), self._deserialize(raw, conn.msgtype)
        except IngestError:
            raise
        except Exception as err:
            msg = f"{self.path}: error while reading messages ({type(err).__name__}: {err}); {_CORRUPT_HINT}."
            raise IngestError(msg) from err


class Ros2Reader(_RosbagsReader):
    """ROS 2 CDR recordings: a single ``.mcap`` file, a ``.db3`` file or a rosbag2 directory."""

    kind = "a ROS 2 recording (MCAP or rosbag2)"

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self._files: list[Any] = []

    @property
    def _store(self) -> Any:
        return ros2_typestore()

    def _open_backend(self) -> Any:
        from rosbags.rosbag2 import Reader

        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            msg = f"{self.path}: directory without metadata.yaml is not a rosbag2 recording; pass the bag directory, a .mcap file or a .bag file."
            raise IngestError(msg)
        reader = Reader(self.path)
        reader.open()
        if self.path.is_dir():
            try:
                self._check_directory(reader)
            except BaseException:
                reader.close()
                raise
        return reader

    def _check_directory(self, reader: Any) -> None:
        """Detect rosbags' silent empty read and fall back to the storage files themselves."""
        if reader.message_count <= 0 or next(iter(reader.messages()), None) is not None:
            return
        from rosbags.rosbag2 import Reader

        files = [Path(storage.path) for storage in reader.storage.storages]
        for file in files:
            sub = Reader(file)
            sub.open()
            self._files.append(sub)
        if sum(1 for f in self._files for _ in f.messages()) == 0:
            msg = f"{self.path}: metadata.yaml counts {reader.message_count} messages but none can be read from {', '.join(p.name for p in files)}; the bag is corrupt or of an unsupported rosbag2 version."
            raise IngestError(msg)

    def _connections(self) -> list[Any]:
        if self._files:
            return [c for f in self._files for c in f.connections]
        return list(self._reader.connections)

    def _raw(self, conns: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        if not self._files:
            yield from self._reader.messages(conns)
            return
        for f in self._files:
            own = [c for c in conns if c.owner is f or c in f.connections]
            if own:
                yield from f.messages(own)

    def _firsts(self, conns: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        if not self._files:
            yield from super()._firsts(conns)
            return
        for f in self._files:
            own = [c for c in conns if c.owner is f or c in f.connections]
            if own:
                yield from itertools.islice(f.messages(own), 1)

    def close(self) -> None:
        for f in self._files:
            try:
                f.close()
            except Exception:  # best effort on close
                continue
        self._files.clear()
        super().close()

    def _deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self._store.deserialize_cdr(raw, msgtype)


class Rosbag1Reader(_RosbagsReader):
    """ROS 1 bags (v2.0), including librealsense's dialect without ``topic`` header fields."""

    kind = "a ROS 1 bag"

    @property
    def _store(self) -> Any:
        return ros1_typestore()

    def _open_backend(self) -> Any:
        from rosbags.rosbag1 import Reader

        reader = Reader(self.path)
        reader.open()
        return reader

    def _deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self._store.deserialize_ros1(raw, msgtype)


READERS: dict[str, type[_RosbagsReader]] = {
    "dir": Ros2Reader,
    ".mcap": Ros2Reader,
    ".db3": Ros2Reader,
    ".bag": Rosbag1Reader,
}
"""Reader class by path suffix (``dir`` = a rosbag2 directory)."""


_MAGIC = {
    b"\x89MCAP": "an MCAP file",
    b"#ROSBAG V2.0": "a ROS 1 bag",
    b"#ROSBAG": "a ROS 1 bag of an unsupported version",
    b"SQLite format 3": "an SQLite database",
    b"\x89PNG": "a PNG image",
    b"\xff\xd8\xff": "a JPEG image",
    b"PK\x03\x04": "a zip archive",
    b"\x1f\x8b": "a gzip file",
    b"\x28\xb5\x2f\xfd": "a zstd-compressed file",
}

_EXPECTED = {".mcap": "an MCAP file", ".bag": "a ROS 1 bag", ".db3": "an SQLite database"}


def _sniff(path: Path) -> str | None:
    """What the first bytes say the file is, if they say anything we know."""
    with path.open("rb") as f:
        head = f.read(16)
    return next((what for magic, what in _MAGIC.items() if head.startswith(magic)), None)


def is_recording(path: Path) -> bool:
    """Whether ``path`` looks like something ingest reads: a ``.mcap`` or ``.bag`` file, a
    rosbag2 directory (its ``metadata.yaml``), or a dataset folder of a known layout
    (:func:`care_maps.ingest.folders.is_dataset_folder`: a ScanNet scene, a TUM sequence, ...), which
    is one recording, not a folder of them."""
    from care_maps.ingest.folders import is_dataset_folder

    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file() or is_dataset_folder(path)
    return path.is_file() and path.suffix.lower() in READERS and path.suffix.lower() != "dir"


def recordings_in(folder: Path) -> list[Path]:
    """The recordings directly inside ``folder`` (any mix of formats, dataset folders among
    them), sorted by name."""
    return sorted(
        p for p in Path(folder).iterdir() if not p.name.startswith(".") and is_recording(p)
    )


def open_reader(path: Path) -> RecordingReader:
    """The reader for ``path`` (not yet entered: use ``with open_reader(p) as reader``).

    A file whose first bytes say it is something else than its suffix promises (a PNG
    renamed ``.bag``) is refused here with both names, before any reader guesses at it.
    """
    path = Path(path)
    if not path.exists():
        msg = f"{path}: no such file or directory; check the recording path."
        raise IngestError(msg)
    key = "dir" if path.is_dir() else path.suffix.lower()
    cls = READERS.get(key)
    if cls is None:
        msg = f"{path}: unknown recording format {path.suffix!r}; pass a .mcap file, a rosbag2 directory or a ROS 1 .bag."
        raise IngestError(msg)
    if key in _EXPECTED:
        found = _sniff(path)
        if found != _EXPECTED[key] and not (found or "").startswith(_EXPECTED[key]):
            what = found or "of no known format (unrecognised leading bytes)"
            msg = f"{path}: is {what}, not {_EXPECTED[key]} as its suffix {path.suffix} says; pass a recording of that format."
            raise IngestError(msg)
    return cls(path)
