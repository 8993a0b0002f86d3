"""``care ingest``: a recording in, a feature store (and optionally a Rerun file) out.

Frames stream from :func:`care_maps.ingest.folders.frames.open_frames` (a recording's
:class:`care_maps.ingest.source.RecordingFrames`, or a dataset folder's
:class:`care_maps.ingest.folders.frames.FolderFrames`), are encoded in batches and go straight into a
:class:`care_maps.core.store.StoreWriter`, so at most one batch of images is held.
The store is committed atomically with a meta.json that records where it came from and
what was dropped; its ``fingerprint`` (source identity + configuration) lets a re-run with
the same inputs return at once (idempotent), while any change to the recording or to the
options rebuilds it.

:func:`run_ingest` takes where things are (the recording, the store), what the store is
made from (:class:`IngestConfig`) and how the job runs (the run's
:class:`care_maps.runtime.execution.Execution`: ``overwrite`` rebuilds a current store, ``progress``
shows a bar).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterable, Iterator
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from care_maps.core.checks import check_numbers
from care_maps.core.codecs import StoreEncoding
from care_maps.core.encoders import Encoder, EncoderOptions, RecordingContext, make_encoder
from care_maps.core.encoders.base import feature_options, recorded_options
from care_maps.core.encoders.record import RECORD_KEY, EncoderRecord
from care_maps.core.errors import IngestError, StoreError
from care_maps.core.fingerprint import config_fields, content_digest
from care_maps.core.fingerprint import fingerprint as content_fingerprint
from care_maps.core.frames import DEFAULT_CAMERA_FRAME, DEFAULT_WORLD_FRAME, Frame
from care_maps.core.notices import notice
from care_maps.core.outputs import (
    OutputKind,
    check_file_output,
    check_output,
    damaged,
    output_lock,
)
from care_maps.core.store import (
    META_FILE,
    SCHEMA_VERSION,
    STORE_OWN,
    Store,
    StoreWriter,
    run_records,
)
from care_maps.ingest.consistency import (
    GeometrySampler,
    check_geometry,
    refuse_unless_consistent,
    source_reading,
)
from care_maps.ingest.folders.frames import Frames, folder_identity, open_frames
from care_maps.ingest.parts import Recording, recording_parts
from care_maps.ingest.runs import (
    RunOptions,
    appended_meta,
    carry_maps,
    check_alignment,
    check_same_encoding,
    check_same_names,
    check_world_frame,
    placed,
)
from care_maps.ingest.select import FrameSelection, FrameSelector
from care_maps.ingest.source import ReadOptions, RecordingFrames
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution
from care_maps.runtime.readahead import read_ahead
from care_maps.runtime.threads import Work, stage_threads, threads_for

__all__ = ["INGEST_VERSION", "IngestConfig", "fingerprint", "request_fingerprint", "run_ingest"]

_NOT_RECORDED = ("rrd",)
"""Fields of :class:`IngestConfig` the store does not record: where its Rerun file goes."""
_READ_NOT_RECORDED = (*ReadOptions.HOW, "format")
"""Fields of :class:`care_maps.ingest.source.ReadOptions` neither fingerprinted nor recorded: the limits
that only refuse, and ``format``, which only picks the layout a folder is read as. The layout
itself is part of the source's identity (fingerprinted) and recorded under ``topics``,
whether it was detected or forced: a forced layout equal to the detected one leaves the
store current, and stores of recordings keep their bytes."""

INGEST_VERSION = "2"
"""Bumped when ingest's output for the same input changes; part of the fingerprint."""


@dataclass(frozen=True)
class IngestConfig:
    """What a store is made from, and the Rerun file logged beside it (``care ingest``'s
    options are generated from it). Where the recording and the store are, and how the job
    runs (:class:`care_maps.runtime.execution.Execution`), are :func:`run_ingest`'s arguments."""

    read: ReadOptions = field(default_factory=ReadOptions)
    """Topic, frame and synchronisation choices."""
    encoder: str | None = None
    """Feature encoder, by name, of those installed (:data:`care_maps.core.encoders.ENCODERS`);
    none stores views without features."""
    encoder_options: EncoderOptions = field(default_factory=EncoderOptions)
    """Weights, device, batch size, ... of the encoder."""
    select: FrameSelection = field(default_factory=FrameSelection)
    """Which synchronised frames to keep (time range, every Nth, enough motion)."""
    vocabulary: str | None = None
    """Vocabulary (bundled name or file) whose text embeddings are cached in the store;
    default the recording's own class names if it has any."""
    rrd: Path | None = None
    """Write a Rerun recording of the ingest here."""
    rrd_every: int | None = None
    """Log the back-projected point cloud of every Nth view; default every view of a short
    recording, else every 10th (:func:`care_maps.ingest.viz.cloud_every`)."""
    store_encoding: StoreEncoding = StoreEncoding.RAW_ZSTD
    """How the store keeps images and features (:mod:`care_maps.core.codecs`); ``png-lists`` is the
    0.1 store, slower to write and read, kept to measure the default against."""

    def __post_init__(self) -> None:
        every = {} if self.rrd_every is None else {"rrd_every": self.rrd_every}
        check_numbers(
            IngestError,
            "ingest config",
            at_least_one={**every, "batch_size": self.encoder_options.batch_size},
        )


def _source_identity(parts: tuple[Path, ...], read: ReadOptions) -> dict[str, Any]:
    """What a recording *is*: its size and checksum (every file of a bag directory or dataset
    folder, with their relative names), not where it lies or when it was touched, so a dataset
    copied to another directory or machine keeps its stores
    (:func:`care_maps.core.fingerprint.content_digest`); for a dataset folder also the layout it is read
    as and what the layout reads it with (:func:`care_maps.ingest.folders.frames.folder_identity`).

    A recording in several files is their total size and a checksum of every file's, in
    whatever order they are given (their content decides the order they are read in), so a
    change to any file rebuilds the store; ``parts`` counts them."""
    if len(parts) > 1:
        digests = [content_digest(part) for part in parts]
        h = hashlib.blake2b(digest_size=16)
        for checksum in sorted(d["blake2b"] for d in digests):
            h.update(checksum.encode())
        return {
            "size": sum(d["size"] for d in digests),
            "blake2b": h.hexdigest(),
            "parts": len(parts),
        }
    identity = content_digest(parts[0])
    layout = folder_identity(parts[0], read)
    return identity if layout is None else {**identity, "layout": layout}


def _digest(config: IngestConfig, source: dict[str, Any], encoder_key: dict[str, Any]) -> str:
    """sha256 of what every store depends on (inputs and options, not where outputs go) and
    ``encoder_key``: what identifies the encoder."""
    options = feature_options(config.encoder_options)
    return content_fingerprint(
        {
            "ingest_version": INGEST_VERSION,
            "schema_version": SCHEMA_VERSION,
            "source": source,
            "read": config_fields(config.read, _READ_NOT_RECORDED),
            "select": config.select,
            "encoder_options": options if encoder_key["encoder"] is not None else None,
            "vocabulary": config.vocabulary,
            "store_encoding": config.store_encoding,
            **encoder_key,
        }
    )


def fingerprint(config: IngestConfig, encoder: Encoder | None, source: dict[str, Any]) -> str:
    """Hash of everything the store's content depends on, the built encoder's identity
    (name, version, dimension) included."""
    built = (
        None
        if encoder is None
        else {"name": encoder.name, "version": encoder.version, "dim": encoder.dim}
    )
    return _digest(config, source, {"encoder": built})


def request_fingerprint(config: IngestConfig, source: dict[str, Any]) -> str:
    """Hash of everything the store depends on that is known *before* the encoder is built:
    the options, the source's identity, a local weights directory's digest and the version of
    the package that runs the model. A re-run whose request matches returns without importing
    torch or loading a model (under a second)."""
    from importlib.metadata import PackageNotFoundError, version

    weights = config.encoder_options.weights
    digest = None
    if weights is not None and Path(weights).expanduser().is_dir():
        from care_maps.core.encoders.record import weights_digest

        digest = weights_digest(Path(weights).expanduser())
    try:
        runtime = {"transformers": version("transformers"), "torch": version("torch")}
    except PackageNotFoundError:
        runtime = {}
    named = config.encoder is not None
    return _digest(
        config,
        source,
        {
            "encoder": config.encoder,
            "weights_digest": digest,
            "runtime": runtime if named else None,
        },
    )


def _up_to_date(job: _Job, fp: str, key: str = "fingerprint") -> bool:
    out = job.out
    if job.run.overwrite or not (out / META_FILE).is_file():
        return False
    try:  # a store whose tables a reader refuses (another layout) is rebuilt, not kept
        meta = Store(out).meta
    except StoreError:
        return False
    # same inputs, and every table as it was committed (size and checksum): a damaged
    # store is rebuilt, not trusted
    first = meta.runs[0] if meta.runs else meta
    if getattr(first, key) != fp or not meta.tables or damaged(out):
        return False
    if meta.runs:  # re-running a script's first ingest keeps the runs appended after it
        notice(
            f"{out}: holds this recording and {len(meta.runs) - 1} more runs appended to it; "
            "kept (pass --force to rebuild it from this recording alone)"
        )
    return True


def _vocabulary(config: IngestConfig, label_names: tuple[str, ...]) -> list[str]:
    if config.vocabulary is None:
        return list(label_names)
    from care_maps.core.vocab import vocabulary_option

    return list(vocabulary_option(config.vocabulary))


def _open_logger(job: _Job, frames: Frames, base: Store | None) -> Any:
    """A Rerun logger writing to a temporary file that :meth:`keep` renames into place; for
    a run appended to ``base``, the store's earlier runs logged first, each on its own
    timeline, and the new run next (:mod:`care_maps.ingest.viz`)."""
    config = job.config
    if config.rrd is None:
        return None
    from care_maps.ingest.viz import IngestLogger, cloud_every

    total = frames.total
    views = None if total is None else -(-total // config.select.every)
    earlier = [] if base is None else run_records(base.meta)
    logger = IngestLogger(
        config.rrd,
        every=cloud_every(config.rrd_every, views),
        world_frame=frames.world_frame or DEFAULT_WORLD_FRAME,
        camera_frame=frames.camera_frame or DEFAULT_CAMERA_FRAME,
        scene=job.out.name,
        runs=len(earlier) + 1,
    )
    if base is not None:
        try:
            _log_store(logger, base)
        except BaseException:
            logger.close()
            logger.discard()
            raise
        logger.start_run(len(earlier))
    return logger


def _log_store(logger: Any, store: Store) -> None:
    """Every view of ``store``, run by run."""
    starts = {run.first_view: k for k, run in enumerate(run_records(store.meta))}
    for view_id, frame in store.iter_frames(extras=False, in_map=False):
        if view_id in starts:
            logger.start_run(starts[view_id])
        logger.log(view_id, frame)


@dataclass(frozen=True)
class _Job:
    """One ingest: the recording, the store it becomes, what it is made from and how the
    job runs."""

    recording: Path
    """The recording, or the first of its files as given."""
    out: Path
    config: IngestConfig
    run: Execution
    parts: tuple[Path, ...]
    """The recording's files (itself, if one)."""
    placement: RunOptions = field(default_factory=RunOptions)
    """Whether the recording is added to the store as one more run, and where its world
    frame lies in the store's."""

    @property
    def source(self) -> Path | tuple[Path, ...]:
        """What is read: the recording, or its files."""
        return self.recording if len(self.parts) == 1 else self.parts


def run_ingest(
    recording: Recording,
    out: Path,
    config: IngestConfig | None = None,
    *,
    run: Execution = DEFAULT_EXECUTION,
    encoder: Encoder | None = None,
    placement: RunOptions | None = None,
) -> Path:
    """Build the store ``out`` from ``recording`` with ``config``; returns the store path.

    ``recording``: a recording, a dataset folder, or the files of one recording written in
    several (split bags or MCAP files, :mod:`care_maps.ingest.parts`), read as one.

    ``placement``: add the recording to the store ``out`` as one more exploration run
    (``append``), or place its world frame in the store's (:mod:`care_maps.ingest.runs`).

    ``encoder`` overrides ``config.encoder`` with an instance (e.g. one built in a test or
    shared across many recordings). Returns at once if the store is up to date (unless
    ``run.overwrite``). Runs on the thread pools of :attr:`care_maps.runtime.threads.Work.DEFAULT`
    whoever calls it (the encoder's forward pass on :attr:`~care_maps.runtime.threads.Work.ENCODE`'s).
    """
    parts = recording_parts(recording)
    job = _Job(parts[0], Path(out), config or IngestConfig(), run, parts, placement or RunOptions())
    with threads_for(Work.DEFAULT):
        return _run_ingest(job, encoder)


def _run_ingest(job: _Job, encoder: Encoder | None) -> Path:
    recording, config, out = job.recording, job.config, job.out
    if not recording.exists():
        msg = f"{recording}: no such file or directory; check the recording path."
        raise IngestError(msg)
    # refused before any work: a path we did not create, the recording itself, ...
    check_output(out, kind=OutputKind.STORE, inputs=job.parts)
    if config.rrd is not None:
        check_file_output(config.rrd, inputs=job.parts)
    source = _source_identity(job.parts, config.read)
    transform = job.placement.world_transform
    if transform is not None:  # the same recording placed elsewhere is another store
        source = {**source, "world_transform": transform.as_json()}
    request = request_fingerprint(config, source) if encoder is None else None
    if job.placement.append:
        return _append(job, encoder, source, request)
    if request is not None and _up_to_date(job, request, "request_fingerprint"):
        return _log_missing_rrd(job)  # before building the encoder: no model is loaded
    # opening the recording checks its topics, camera info and pose source (a folder its
    # layout's files): a source that cannot be read is refused before a model is loaded
    with open_frames(job.source, config.read) as frames:
        if encoder is None and config.encoder is not None:
            encoder = make_encoder(config.encoder, config.encoder_options)
        with output_lock(out):
            check_output(out, kind=OutputKind.STORE, inputs=job.parts)  # as the lock found it
            fp = fingerprint(config, encoder, source)
            if _up_to_date(job, fp):
                return _log_missing_rrd(job)
            _build(job, frames, encoder, source, fp, request)
    return out


def _append(
    job: _Job, encoder: Encoder | None, source: dict[str, Any], request: str | None
) -> Path:
    """Add the recording to the store ``job.out`` as one more run (:mod:`care_maps.ingest.runs`);
    a run the store holds already (same recording, options and placement) is not added again."""
    config, out = job.config, job.out
    where = " ".join(str(p) for p in job.parts)
    if not (out / META_FILE).is_file():
        msg = f"{out}: no store to append to; ingest the first run without --append."
        raise IngestError(msg)
    if job.run.overwrite:  # two opposite asks: one is not silently dropped
        msg = (
            f"{out}: --force rebuilds the store from this recording alone and --append adds it "
            "to the store's runs; give one of them."
        )
        raise IngestError(msg)
    base = Store(out)
    check_same_encoding(base, _recorded(config), where)
    if request is not None and any(
        r.request_fingerprint == request for r in run_records(base.meta)
    ):
        return _log_missing_rrd(job)
    with open_frames(job.source, config.read) as frames:
        # what the opened recording says is checked before the model loads or a frame is read
        check_world_frame(base, frames.world_frame, job.placement.world_transform, where)
        check_same_names(base, _vocabulary(config, frames.label_names), frames.label_names, where)
        if encoder is None and config.encoder is not None:
            encoder = make_encoder(config.encoder, config.encoder_options)
        with output_lock(out):
            base = Store(out)  # as the lock found it
            fp = fingerprint(config, encoder, source)
            if any(r.fingerprint == fp for r in run_records(base.meta)):
                return _log_missing_rrd(job)
            _build(job, frames, encoder, source, fp, request, base=base)
    return out


def _log_missing_rrd(job: _Job) -> Path:
    """An up-to-date store asked for a Rerun file it lacks: the file is written from the
    store's views, so nothing is ingested again and the maps built in the store stay."""
    rrd = job.config.rrd
    if rrd is None or rrd.is_file():
        return job.out
    from care_maps.ingest.viz import IngestLogger, cloud_every

    store = Store(job.out)
    logger = IngestLogger(
        rrd,
        every=cloud_every(job.config.rrd_every, store.num_views),
        world_frame=store.meta.world_frame or DEFAULT_WORLD_FRAME,
        camera_frame=store.meta.camera_frame or DEFAULT_CAMERA_FRAME,
        scene=job.out.name,
        runs=len(run_records(store.meta)),
    )
    try:
        _log_store(logger, store)
    except BaseException:
        logger.close()
        logger.discard()
        raise
    logger.close()
    logger.keep()
    return job.out


def _say_maps_go(out: Path, *, forced: bool) -> None:
    """As a rebuilt store replaces the old one, name the maps made from the old one: the
    new store replaces the directory whole, so they go with it (they describe other views).
    Said once the new store is written, just before the swap, so a rebuild that fails (and
    keeps the old store and its maps) says nothing of them."""
    if not (out / META_FILE).is_file():
        return
    made = sorted(p.name for p in out.iterdir() if p.name not in STORE_OWN and p.name[0] != ".")
    why = "as asked (--force)" if forced else "for another recording or other ingest options"
    if made:
        notice(
            f"{out}: rebuilt {why}, so the maps made from the old store go with it "
            f"({', '.join(made)}); run `care fuse` again after"
        )


def _carry_maps(base: Store, tmp: Path) -> None:
    """Before the store with one more run replaces ``base``: its maps carried over, to be
    grown (the grid) or built again (:func:`care_maps.ingest.runs.carry_maps`)."""
    if carry_maps(base.path, tmp):
        notice(
            f"{base.path}: one more run added; `care fuse grid` adds its views to the grid "
            "kept from the earlier runs, the other maps are built again"
        )


def _build(
    job: _Job,
    frames: Frames,
    encoder: Encoder | None,
    source: dict[str, Any],
    fp: str,
    request: str | None,
    *,
    base: Store | None = None,
) -> None:
    """Stream ``frames`` into a new store and commit it in place of ``job.out``; with a
    ``base`` store (an appended run) its views first, as they are."""
    config = job.config
    # a recording's first file by time, once its files are open
    recording = job.recording if len(job.parts) == 1 else frames.path
    vocab = _vocabulary(config, frames.label_names)
    if encoder is not None:
        encoder.prepare(RecordingContext(recording, frames.label_names))
    info = encoder.info(vocab) if encoder is not None else None
    # the text side first: a missing text table or model fails before any frame is read;
    # on every core, as the forward pass (a vocabulary's prompts are a text tower's batches:
    # ScanNet200's on ViT-B/32, 4.3 s on one of 2 cores, 2.3 s on both)
    text = None
    if encoder is not None and vocab:
        with threads_for(Work.ENCODE):
            text = encoder.encode_text(vocab)
    logger = _open_logger(job, frames, base)
    bar = tqdm(
        total=frames.total,
        desc=f"ingest {recording.name}"
        + (f" (+{len(job.parts) - 1})" if len(job.parts) > 1 else ""),
        unit="frame",
        disable=not job.run.progress,
    )
    try:
        with StoreWriter(job.out, info, encoding=config.store_encoding) as writer:
            if base is not None:
                writer.copy_views(base)
            selector = FrameSelector(config.select)
            sampler = GeometrySampler()
            _stream(
                placed(iter(frames), job.placement.world_transform),
                writer,
                encoder,
                config.encoder_options.batch_size,
                logger,
                bar,
                selector,
                job.run.read_ahead,
                sampler,
            )
            # before anything is committed: geometry the views disagree on is refused
            where: Path | str = recording
            if isinstance(frames, RecordingFrames) and len(job.parts) > 1:
                where = frames.where  # the recording's files
            reading = source_reading(where, frames, config.read)
            verdict = check_geometry(sampler, reading)
            refuse_unless_consistent(
                verdict, reading, sampler.K, accept=config.read.accept_geometry
            )
            if text is not None:
                writer.set_text(vocab, text)
            meta = _meta(job, frames, source, fp, vocab, encoder)
            meta["geometry"] = verdict.as_json()
            if not verdict.passed:  # kept as given, as asked (--accept-geometry)
                meta["geometry"]["accepted"] = True
            meta["counts"]["skipped"] = dict(sorted(selector.skipped.items()))
            meta["request_fingerprint"] = request
            if base is not None:  # one more run: checked against the store's, then recorded
                label = str(where)
                sample = [s for run in sampler.samples() for s in run]
                alignment = check_alignment(base, sample, label, accept=config.read.accept_geometry)
                meta = appended_meta(base, meta, writer.num_views, alignment, job.placement)
            writer.commit(
                meta,
                replacing=(
                    (lambda: _say_maps_go(job.out, forced=job.run.overwrite))
                    if base is None
                    else (lambda: _carry_maps(base, writer.tmp))
                ),
            )
    except BaseException:
        bar.leave = False  # the error is the one line left on the terminal
        if logger is not None:
            logger.close()
            logger.discard()
        raise
    finally:
        bar.close()
    if logger is not None:
        logger.close()
        logger.keep()


def _stream(
    frames: Iterable[Frame],
    writer: StoreWriter,
    encoder: Encoder | None,
    batch_size: int,
    logger: Any,
    bar: tqdm,
    selector: FrameSelector,
    depth: int,
    sampler: GeometrySampler,
) -> None:
    """Frames to the store in three stages that overlap on a machine's cores: the recording
    read and decoded up to ``depth`` frames ahead on one background thread
    (:func:`care_maps.runtime.readahead.read_ahead`); the kept frames batched and made ready
    for the model (:meth:`Encoder.prepare_views`: resized, normalised) one batch ahead on a
    second; and, in this thread, the model's forward pass and the store's writer, whose own
    thread encodes the images. So the next batch is read and prepared while this one is in
    the model (``--read-ahead 0``: all in one thread, the same store)."""
    batches = _batches(frames, selector, bar, max(1, batch_size), depth)
    with closing(read_ahead(_prepared(batches, encoder), min(depth, 1))) as ahead:
        for batch, inputs in ahead:
            features = None
            if encoder is not None:
                with threads_for(Work.ENCODE):  # the model's products scale with cores
                    features = encoder.encode_prepared(inputs)
                if len(features) != len(batch):
                    msg = f"encoder {encoder.name!r} returned {len(features)} feature maps for {len(batch)} views"
                    raise IngestError(msg)
            for i, frame in enumerate(batch):
                if logger is not None:
                    logger.log(writer.num_views, frame)
                sampler.add(frame)
                writer.add(frame, None if features is None else np.asarray(features[i]))


def _prepared(
    batches: Iterator[list[Frame]], encoder: Encoder | None
) -> Iterator[tuple[list[Frame], Any]]:
    """Each batch with the model's inputs made from it (:meth:`Encoder.prepare_views`), on
    one thread of torch's (:func:`care_maps.runtime.threads.stage_threads`): the forward
    pass it overlaps has the cores."""
    started = False
    for batch in batches:
        if encoder is None:
            yield batch, None
            continue
        if not started:  # in the thread that prepares, before its first torch operation
            stage_threads(Work.DEFAULT)
            started = True
        yield batch, encoder.prepare_views(batch)


def _batches(
    frames: Iterable[Frame], selector: FrameSelector, bar: tqdm, size: int, depth: int
) -> Iterator[list[Frame]]:
    """The frames ``selector`` keeps, in batches of ``size`` (the last one shorter), read
    ``depth`` frames ahead."""
    batch: list[Frame] = []
    with closing(read_ahead(frames, depth)) as ahead:
        for frame in ahead:
            bar.update(1)
            if not selector.keep(frame):
                if selector.done:
                    break
                continue
            batch.append(frame)
            if len(batch) >= size:
                yield batch
                batch = []
    if batch:
        yield batch


def _files(job: _Job, frames: Frames) -> dict[str, Any]:
    """A recording in several files: each file, in the order read (its path relative to the
    store, name and size; their checksums are the source's); nothing for one."""
    if len(job.parts) == 1 or not isinstance(frames, RecordingFrames):
        return {}
    return {
        "files": [
            {
                "path": os.path.relpath(part.resolve(), job.out.resolve()),
                "name": part.name,
                "size": part.stat().st_size if part.is_file() else None,
            }
            for part in frames.parts
        ]
    }


def _recorded(config: IngestConfig) -> dict[str, Any]:
    """The ingest options ``meta.json`` records: what the store is made with."""
    recorded = config_fields(config, _NOT_RECORDED)
    for name in _READ_NOT_RECORDED:  # not what the store is (see there)
        recorded["read"].pop(name, None)
    recorded["encoder_options"] = recorded_options(config.encoder_options)
    return recorded


def _meta(
    job: _Job,
    frames: Frames,
    source: dict[str, Any],
    fp: str,
    vocab: list[str],
    encoder: Encoder | None,
) -> dict[str, Any]:
    config = job.config
    described = frames.describe()
    first = job.recording if len(job.parts) == 1 else frames.path
    recorded = _recorded(config)
    record = (
        None if encoder is None else EncoderRecord.of(encoder, config.encoder_options).as_json()
    )
    return {
        RECORD_KEY: record,
        "fingerprint": fp,
        "source": {
            # relative to the store: no machine's absolute path inside a store
            "path": os.path.relpath(first.resolve(), job.out.resolve()),
            "name": first.name,
            **source,
            **_files(job, frames),
        },
        "topics": described["topics"],
        "world_frame": described["world_frame"],
        "camera_convention": described.get("camera_convention"),
        "camera_frame": described["camera_frame"],
        "distortion": [lens.as_json() for lens in frames.distortions],
        "label_names": described["label_names"],
        "vocabulary": vocab,
        "counts": frames.stats.as_dict(),
        "config": recorded,
    }
