"""``care ingest`` (a recording or dataset folder into a feature store) and ``care topics``
(what is in it).

Their options are generated from :class:`care_maps.ingest.pipeline.IngestConfig`,
:class:`care_maps.core.encoders.EncoderOptions`, :class:`care_maps.ingest.source.ReadOptions`,
:class:`care_maps.ingest.select.FrameSelection` and, for how the job runs,
:class:`care_maps.runtime.execution.Execution` (:mod:`care_maps.cli.options`).
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Annotated

import typer

from care_maps.cli.choices import EncoderName, Perception
from care_maps.cli.options import Options, config_options
from care_maps.core.encoders.base import EncoderOptions
from care_maps.ingest.pipeline import IngestConfig
from care_maps.ingest.runs import RunOptions
from care_maps.ingest.select import FrameSelection
from care_maps.ingest.source import ReadOptions
from care_maps.runtime.execution import Execution

__all__ = ["register"]

_READ = "Topics and frames"
"""Help panel of the reading options, shared by ``care ingest`` and ``care topics``."""
_SOURCE_HELP = (
    "MCAP file, rosbag2 directory, ROS 1 .bag, or a dataset folder (ScanNet, Replica, TUM "
    "RGB-D, ICL-NUIM/Redwood, Matterport3D, generic: docs/inputs.md); several files of one "
    "recording (split bags or MCAP files, e.g. run_*.bag) are read as one, in time order."
)

read_options = config_options(
    "read", ReadOptions, extra={f.name: {"rich_help_panel": _READ} for f in fields(ReadOptions)}
)
"""The :class:`care_maps.ingest.source.ReadOptions` options of both commands."""


@config_options(
    "run",
    Execution,
    only=("overwrite", "read_ahead"),
    names={"overwrite": "force"},
    extra={"overwrite": {"help": "Rebuild even if the store is up to date."}},
)
@config_options(
    "job",
    IngestConfig,
    only=("encoder", "vocabulary", "rrd", "rrd_every", "store_encoding"),
    extra={
        "encoder": {"type": EncoderName},
        "rrd_every": {"min": 1},
        "vocabulary": {"help": "Class names whose text embeddings to cache: a bundled "
                       "vocabulary name, a file, or comma-separated names."},
    },
)  # fmt: skip
@config_options(
    "encoding",
    EncoderOptions,
    extra={"batch_size": {"min": 1}, "perception": {"type": Perception}},
)
@read_options
@config_options("selection", FrameSelection)
@config_options(
    "placement",
    RunOptions,
    extra={"append": {"rich_help_panel": "Runs"}, "world_transform": {"rich_help_panel": "Runs"}},
)
def ingest(
    recording: Annotated[list[Path], typer.Argument(help=_SOURCE_HELP)],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            "-o",
            help="Store directory to create (replaced atomically if it exists and is stale).",
        ),
    ],
    job: Options[IngestConfig] = None,  # type: ignore[assignment]
    encoding: Options[EncoderOptions] = None,  # type: ignore[assignment]
    read: Options[ReadOptions] = None,  # type: ignore[assignment]
    selection: Options[FrameSelection] = None,  # type: ignore[assignment]
    placement: Options[RunOptions] = None,  # type: ignore[assignment]
    run: Options[Execution] = None,  # type: ignore[assignment]
) -> None:
    """Read a robot recording or a dataset folder into a feature store (views, poses,
    features)."""
    from care_maps.cli.summary import geometry_line, ingest_line, runs_lines
    from care_maps.ingest import ingest

    config = job.config(
        read=read.config(),
        encoder_options=encoding.config(),
        select=selection.config(),
    )
    path = ingest(
        _one_or_parts(recording), out, config, run=run.config(), placement=placement.config()
    ).path
    for line in (ingest_line(path), geometry_line(path), *runs_lines(path)):
        if line is not None:
            typer.echo(line)


def _one_or_parts(paths: list[Path]) -> Path | list[Path]:
    """The command line's recording: one path, or one recording's files."""
    return paths[0] if len(paths) == 1 else paths


@read_options
@config_options(
    "placement",
    RunOptions,
    only=("world_transform",),
    extra={"world_transform": {"rich_help_panel": "Runs"}},
)
def topics(
    recording: Annotated[list[Path], typer.Argument(help=_SOURCE_HELP)],
    read: Options[ReadOptions] = None,  # type: ignore[assignment]
    placement: Options[RunOptions] = None,  # type: ignore[assignment]
    store: Annotated[
        Path | None,
        typer.Option(
            "--store",
            help="A store to append the recording to: also say what `care ingest REC --out "
            "STORE --append` would find of its first views (its world frame, its overlap "
            "with the store's runs).",
            rich_help_panel="Runs",
        ),
    ] = None,
    stamps: Annotated[
        bool,
        typer.Option(
            "--stamps",
            help="Print only the stamps (ns) of the colour images ingest would keep, one a "
            "line: the keys of a --precomputed features file.",
        ),
    ] = False,
) -> None:
    """List a recording's topics, types and counts, and what ingest would pick; for a dataset
    folder, its layout, views and what it reads them with."""
    from care_maps.core.errors import CareError
    from care_maps.ingest.folders.frames import open_frames, resolve_layout
    from care_maps.ingest.parts import SplitReader, open_recording
    from care_maps.ingest.source import RecordingFrames

    options = read.config()
    source = _one_or_parts(recording)
    if stamps:
        with open_frames(source, options) as frames:
            for frame in frames:
                typer.echo(str(frame.stamp_ns))
        return
    if isinstance(source, Path) and resolve_layout(source, options.format) is not None:
        _folder_topics(source, options)
        return

    with open_recording(source) as reader:
        listed = reader.topics()
        if isinstance(reader, SplitReader):
            names = ", ".join(str(p) for p in reader.parts)
            typer.echo(f"one recording in {len(reader.parts)} files, in time order: {names}")
    width = max((len(n) for n in listed), default=0)
    for info in listed.values():
        typer.echo(f"{info.name:<{width}}  {info.msgtype:<36} {info.count:>7}")
    from care_maps.ingest.consistency import TOPICS_VIEWS, sample_frames, topics_lines
    from care_maps.ingest.runs import append_lines, placed

    runs = placement.config()
    if store is not None:  # a store that is not one is its own error, not auto-detection's
        from care_maps.core.store import Store

        Store(store)
    try:
        with RecordingFrames(source, options) as frames:
            chosen = frames.describe()
            sampler = sample_frames(placed(iter(frames), runs.world_transform), TOPICS_VIEWS)
            geometry = topics_lines(frames.where, frames, options, sampler)
            if store is not None:
                sample = [s for run in sampler.samples() for s in run]
                geometry += append_lines(
                    store, sample, frames.world_frame, runs, frames.where,
                    accept=options.accept_geometry,
                )  # fmt: skip
    except CareError as err:
        typer.echo(f"auto-detection: {err}")
        raise typer.Exit(1) from err
    sel = chosen["topics"]
    typer.echo("ingest would use:")
    for role in ("rgb", "depth", "camera_info", "pose_source", "class_names"):
        typer.echo(f"  {role:<12} {sel[role]}")
    typer.echo(f"  {'tf':<12} {', '.join(sel['tf']) or None}")
    pose = chosen.get("pose")
    if pose:
        typer.echo(f"  {'pose':<12} {pose['from']}: {pose['reason']}")
    typer.echo(f"  {'extras':<12} {sel['extras'] or None}")
    typer.echo(f"  world frame  {chosen['world_frame']}, camera frame {chosen['camera_frame']}")
    axes = chosen.get("camera_convention")
    if axes:
        typer.echo(f"  camera axes  {axes['convention']} ({axes['reason']})")
    for line in geometry:
        typer.echo(line)


def _folder_topics(folder: Path, options: ReadOptions) -> None:
    """``care topics`` of a dataset folder: the layout, its views (and those it leaves out),
    its files, camera and frames."""
    from care_maps.ingest.consistency import topics_lines
    from care_maps.ingest.folders.frames import FolderFrames

    with FolderFrames(folder, options) as frames:
        chosen = frames.describe()
        stats = frames.stats
        geometry = topics_lines(folder, frames, options)
    layout = dict(chosen["topics"])
    kind, views = layout.pop("layout"), layout.pop("views")
    dropped = dict(stats.dropped)
    typer.echo(
        f"dataset folder, layout {kind}: {views} views of {stats.rgb_messages} colour images"
        + (f", dropped {dropped}" if dropped else "")
    )
    typer.echo("ingest would use:")
    for key, value in layout.items():
        typer.echo(f"  {key:<12} {value}")
    typer.echo(f"  world frame  {chosen['world_frame']}, camera frame {chosen['camera_frame']}")
    for line in geometry:
        typer.echo(line)


def register(app: typer.Typer) -> None:
    """Add ``ingest`` and ``topics`` to ``app``."""
    app.command("ingest")(ingest)
    app.command("topics")(topics)
