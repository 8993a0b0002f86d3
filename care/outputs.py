"""Output safety: what a ``care`` command may replace, one writer per output, no leftovers.

Every directory a command creates (a store, an evaluation, a ``care run`` output) carries
:data:`MARKER`, a small JSON file naming its kind. A command replaces or writes into an
existing directory only when it carries the marker of the right kind; an ``--out`` that is
a regular file, a directory holding anything else, the input recording, a path inside it
or one of its ancestors is refused in one line before any work (:func:`check_output`).

One writer at a time: :func:`output_lock` takes an advisory ``fcntl.flock`` on a hidden
sibling ``.<name>.lock``; a second writer waits for the first and then finds its work done.

Temporaries are named ``.<name>.tmp-<pid>`` (also ``.old-<pid>``, ``.building-<pid>``),
removed on every error path (:func:`staged`), and those of processes that no longer run are
swept at the start of the next run in the same place (:func:`sweep_stale`).

Integrity: :func:`file_digest` (size + BLAKE2b) is the one checksum of a table; a store's
``meta.json`` lists its tables' digests at commit, and tables written into a marked
directory later (maps) are listed in the marker (:func:`record_table`). :func:`damaged`
compares them with what is on disk.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import re
import shutil
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from care.errors import OutputError

__all__ = [
    "MARKER",
    "REBUILD",
    "atomic_write_text",
    "check_file_output",
    "check_output",
    "damaged",
    "disk_full",
    "evaluation_output",
    "file_digest",
    "is_ours",
    "output_lock",
    "owned_output",
    "pid_alive",
    "rebuild_hint",
    "record_table",
    "remove_path",
    "staged",
    "sweep_stale",
    "write_atomic",
    "write_marker",
]

MARKER = "care-output.json"
"""File whose presence marks a directory as written by ``care`` (and of which kind)."""

_STALE = re.compile(r"^\..+\.(?:tmp|old|building)-(\d+)(?:\.[A-Za-z0-9]+)?$")
"""Names of staged temporaries: ``.<name>.tmp-<pid>`` (optionally with a suffix)."""

_CHUNK = 1 << 20

REBUILD = {
    "views": "care ingest {recording} --out {store} --force",
    "features": "care ingest {recording} --out {store} --force",
    "text": "care ingest {recording} --out {store} --force",
    "meta": "care ingest {recording} --out {store} --force",
    "cells": "care fuse grid {store} --overwrite",
    "cell_views": "care fuse grid {store} --overwrite",
    "instances": "care fuse instances {store} --overwrite",
    "instance_views": "care fuse instances {store} --overwrite",
    "scene_points": "care fuse instances {store} --overwrite",
}
"""Table name -> the command that rebuilds it (``{store}``, ``{recording}`` filled in)."""


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs (on this machine's PID namespace)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it runs, as another user
        return True
    return True


def remove_path(path: Path) -> None:
    """Remove a file or directory tree if it exists (a temporary of ours)."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def sweep_stale(directory: Path, name: str | None = None) -> list[Path]:
    """Remove staged temporaries in ``directory`` whose process no longer runs; with
    ``name``, only those of that output (``.<name>.tmp-<pid>``, ...): a directory that is not
    ours may hold the user's own files of a similar pattern."""
    directory = Path(directory)
    removed: list[Path] = []
    if not directory.is_dir():
        return removed
    try:
        entries = list(directory.iterdir())
    except OSError:
        return removed
    for entry in entries:
        m = _STALE.match(entry.name)
        if m is None or (name is not None and not entry.name.startswith(f".{name}.")):
            continue
        pid = int(m.group(1))
        if pid == os.getpid() or pid_alive(pid):
            continue
        remove_path(entry)
        removed.append(entry)
    return removed


def _tree_size(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    total = 0
    for p in path.rglob("*"):
        with contextlib.suppress(OSError):
            if p.is_file():
                total += p.stat().st_size
    return total


def _human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def is_disk_full(err: BaseException) -> bool:
    """ENOSPC, EDQUOT or EFBIG (a file-size limit): no more bytes can be written."""
    return isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def disk_full(target: Path, written: int, err: OSError) -> OutputError:
    """The one-line error of a full disk (or file-size limit) while writing ``target``."""
    where = Path(target).parent
    while not where.exists() and where != where.parent:
        where = where.parent
    try:
        free = shutil.disk_usage(where).free
    except OSError:
        free = 0
    reason = "file-size limit reached" if err.errno == errno.EFBIG else "no space left on device"
    need = (
        f"after writing {_human(written)}; it needs more than {_human(written)} " if written else ""
    )
    msg = (
        f"{target}: {reason} {need}({_human(free)} free on {where}); free space (or raise "
        "the limit) and re-run; nothing half-written was left behind"
    )
    return OutputError(msg)


@contextlib.contextmanager
def staged(path: Path, *, directory: bool = False) -> Iterator[Path]:
    """A temporary sibling ``.<name>.tmp-<pid>`` of ``path``, removed on any error.

    The caller moves it into place (``os.replace``) before leaving the block. A full disk
    becomes :func:`disk_full`'s one-line error, after the temporary has been removed.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    remove_path(tmp)
    if directory:
        tmp.mkdir(parents=True)
    try:
        yield tmp
    except BaseException as err:
        written = _tree_size(tmp) if tmp.exists() else 0
        remove_path(tmp)
        if is_disk_full(err):
            raise disk_full(path, written, err) from err  # type: ignore[arg-type]
        raise
    remove_path(tmp)


def write_atomic(path: Path, write: Callable[[Path], object]) -> None:
    """Run ``write(tmp)`` on a staged temporary of ``path`` and rename it into place (the
    parent is created; nothing is left behind on failure)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with staged(path) as tmp:
        write(tmp)
        tmp.replace(path)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a staged temporary renamed over it."""
    with staged(path) as tmp:
        with tmp.open("w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        tmp.replace(path)


def file_digest(path: Path) -> dict[str, Any]:
    """``{"size": bytes, "blake2b": hex}`` of a file: the one checksum of a table."""
    h = hashlib.blake2b(digest_size=16)
    size = 0
    with Path(path).open("rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return {"size": size, "blake2b": h.hexdigest()}


# -- markers ----------------------------------------------------------------------------


def read_marker(directory: Path) -> dict[str, Any] | None:
    """The marker of ``directory`` (None if it has none or it is unreadable)."""
    path = Path(directory) / MARKER
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def is_ours(directory: Path, kind: str | None = None) -> bool:
    """Whether ``directory`` carries our marker (of ``kind`` when given)."""
    marker = read_marker(directory)
    return marker is not None and (kind is None or marker.get("kind") == kind)


def write_marker(
    directory: Path, kind: str, tables: dict[str, Any] | None = None, source: str | None = None
) -> None:
    """Mark ``directory`` as a ``kind`` output of ours (keeping recorded tables); ``source``:
    the input it was made from (so the rebuild command is known even without meta.json)."""
    directory = Path(directory)
    old = read_marker(directory) or {}
    marker = {"kind": kind, "tables": {**old.get("tables", {}), **(tables or {})}}
    if source or old.get("source"):
        marker["source"] = source or old.get("source")
    atomic_write_text(directory / MARKER, json.dumps(marker, indent=1, sort_keys=True))


def record_table(path: Path) -> None:
    """List ``path``'s digest in its directory's marker, if the directory is ours."""
    path = Path(path)
    marker = read_marker(path.parent)
    if marker is None or path.name.startswith("."):  # not ours, or a staged temporary
        return
    write_marker(path.parent, marker.get("kind", "store"), {path.name: file_digest(path)})


def _recorded(directory: Path) -> dict[str, dict[str, Any]]:
    tables: dict[str, dict[str, Any]] = {}
    marker = read_marker(directory)
    if marker:
        tables.update(marker.get("tables") or {})
    meta = Path(directory) / "meta.json"
    if meta.is_file():
        with contextlib.suppress(OSError, ValueError):
            tables.update(json.loads(meta.read_text()).get("tables") or {})
    return tables


def damaged(
    directory: Path, names: Iterable[str] | None = None, *, checksum: bool = True
) -> list[str]:
    """File names of recorded tables of ``directory`` that are missing or changed.

    ``names``: only these files (default every recorded one); ``checksum=False`` compares
    sizes only (a stat: cheap enough for every open).
    """
    directory = Path(directory)
    recorded = _recorded(directory)
    wanted = recorded if names is None else {n: recorded[n] for n in names if n in recorded}
    bad = []
    for name, expected in sorted(wanted.items()):
        path = directory / name
        try:
            size = path.stat().st_size
        except OSError:
            bad.append(name)
            continue
        if size != expected.get("size") or (
            checksum and file_digest(path).get("blake2b") != expected.get("blake2b")
        ):
            bad.append(name)
    return bad


def rebuild_hint(store: Path, table: str) -> str:
    """The command that rebuilds ``table`` (a file or table name) of the store ``store``."""
    name = Path(table).name.removesuffix(".parquet").removesuffix(".json")
    recording = (read_marker(store) or {}).get("source") or "RECORDING"
    meta = Path(store) / "meta.json"
    with contextlib.suppress(OSError, ValueError, AttributeError, KeyError, TypeError):
        recording = json.loads(meta.read_text())["source"]["path"]
    if recording != "RECORDING":  # recorded relative to the store
        recording = os.path.normpath(Path(store) / recording)
    template = REBUILD.get(name, "care ingest {recording} --out {store} --force")
    return "`" + template.format(store=store, recording=recording) + "`"


# -- where outputs may go ------------------------------------------------------------------


def _same_or_under(a: Path, b: Path) -> bool:
    """Whether ``a`` is ``b`` or lies inside it."""
    return a == b or b in a.parents


def check_output(out: Path, *, kind: str, inputs: Iterable[Path] = (), flag: str = "--out") -> None:
    """Refuse, in one line, an output directory this command must not replace or fill.

    Refused: a regular file (or a path under one), an input or a path inside an input or
    an ancestor of one, an unwritable parent, and an existing non-empty directory without
    our marker of ``kind``.
    """
    out = Path(out)
    resolved = out.resolve()
    for inp in inputs:
        r = Path(inp).resolve()
        if _same_or_under(resolved, r):
            msg = f"{flag} {out}: is the input {inp} or inside it; refusing to write there (choose another {flag})"
            raise OutputError(msg)
        if _same_or_under(r, resolved):
            msg = f"{flag} {out}: contains the input {inp}; refusing to replace it (choose another {flag})"
            raise OutputError(msg)
    for parent in [resolved, *resolved.parents]:
        if parent.exists() and not parent.is_dir():
            what = "is a regular file" if parent == resolved else f"lies under the file {parent}"
            msg = f"{flag} {out}: {what}; not replaced (choose a directory path)"
            raise OutputError(msg)
    if resolved.is_dir():
        marker = read_marker(resolved)
        if marker is None:
            if any(resolved.iterdir()):
                msg = (
                    f"{flag} {out}: directory holds files care did not write (no {MARKER}); "
                    f"not replaced (choose a new or empty directory)"
                )
                raise OutputError(msg)
        elif marker.get("kind") != kind:
            msg = f"{flag} {out}: is a care {marker.get('kind')} directory, not a {kind}; choose another {flag}"
            raise OutputError(msg)
    existing = next(p for p in [resolved, *resolved.parents] if p.exists())
    if not os.access(existing, os.W_OK | os.X_OK):
        msg = f"{flag} {out}: permission denied: cannot write in {existing} (fix its permissions or choose another {flag})"
        raise OutputError(msg)


_RRD_MAGIC = (b"RRF0", b"RRF1", b"RRF2")


def check_file_output(
    path: Path,
    *,
    inputs: Iterable[Path] = (),
    flag: str = "--rrd",
    magic: tuple[bytes, ...] = _RRD_MAGIC,
) -> None:
    """Refuse an output file that is a directory, an input, or an existing file of other
    content (one whose first bytes are not ``magic``)."""
    path = Path(path)
    resolved = path.resolve()
    for inp in inputs:
        r = Path(inp).resolve()
        if _same_or_under(resolved, r) or r in resolved.parents:
            msg = f"{flag} {path}: is or lies inside the input {inp}; choose another {flag}"
            raise OutputError(msg)
    for parent in resolved.parents:
        if parent.exists() and not parent.is_dir():
            msg = f"{flag} {path}: lies under the regular file {parent}; choose another {flag}"
            raise OutputError(msg)
    if resolved.is_dir():
        msg = f"{flag} {path}: is a directory; give a file path"
        raise OutputError(msg)
    if resolved.is_file() and resolved.stat().st_size:
        with resolved.open("rb") as f:
            head = f.read(4)
        if not head.startswith(magic):
            msg = f"{flag} {path}: exists and is not a file care wrote; not overwritten (choose another {flag})"
            raise OutputError(msg)


@contextlib.contextmanager
def output_lock(out: Path, *, wait: bool = True) -> Iterator[None]:
    """Hold an advisory lock on output ``out`` (a sibling ``.<name>.lock``) for the block.

    A second writer waits for the first (saying so on stderr), or with ``wait=False``
    fails in one line. The stale temporaries of dead writers are swept once it is held.
    The lock file is removed on release; a waiter that then holds a removed file's lock
    notices (its inode is gone) and locks the new one, so two writers never both hold it.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    lock_path = out.parent / f".{out.name}.lock"
    while True:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                if not wait:
                    msg = f"{out}: being written by another care process (pid {holder}); wait for it to finish"
                    raise OutputError(msg) from None
                print(f"{out}: waiting for care process {holder} writing it", file=sys.stderr)
                fcntl.flock(fd, fcntl.LOCK_EX)
            try:
                same = lock_path.stat().st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
        except BaseException:
            os.close(fd)
            raise
        if same:
            break
        os.close(fd)  # the holder removed that file: lock the current one
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        sweep_stale(out.parent, out.name)
        if out.is_dir() and is_ours(out):
            sweep_stale(out)
        try:
            yield
        except OSError as err:  # a full disk the staged writers did not already report
            if is_disk_full(err):
                raise disk_full(out, 0, err) from err
            raise
    finally:
        with contextlib.suppress(OSError):
            lock_path.unlink()
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def owned_output(out: Path, kind: str, inputs: Iterable[Path] = ()) -> Iterator[Path]:
    """Check ``out`` (:func:`check_output`), lock it, create and mark it; yield it. A
    directory this call created is removed again if the work inside fails."""
    out = Path(out)
    check_output(out, kind=kind, inputs=inputs)
    with output_lock(out):
        check_output(out, kind=kind, inputs=inputs)
        created = not out.exists()
        out.mkdir(parents=True, exist_ok=True)
        if not is_ours(out, kind):
            write_marker(out, kind)
        try:
            yield out
        except BaseException:
            if created:  # made by this run, which failed: leave nothing behind
                remove_path(out)
            raise


def evaluation_output(
    out: Path, stores: Iterable[Path] = ()
) -> contextlib.AbstractContextManager[Path]:
    """An evaluation directory of ours at ``out`` (never one of the ``stores`` or inside one)."""
    return owned_output(out, "eval", stores)
