"""``care ingest`` (a recording into a feature store) and ``care topics`` (what is in it)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from care_cli.choices import EncoderName, Perception

__all__ = ["register"]

_READ = "Topics and frames"


def _read_options(
    rgb: str | None,
    depth: str | None,
    camera_info: str | None,
    pose_source: str | None,
    world_frame: str | None,
    camera_frame: str | None,
    max_dt: float,
    static_pose: bool,
):  # -> ReadOptions (imported lazily to keep `care --help` fast)
    from ingest.source import ReadOptions

    return ReadOptions(
        rgb=rgb,
        depth=depth,
        camera_info=camera_info,
        pose_source=pose_source,
        world_frame=world_frame,
        camera_frame=camera_frame,
        max_dt=max_dt,
        static_pose=static_pose,
    )


RgbOpt = Annotated[
    str | None, typer.Option("--rgb", help="Colour image topic.", rich_help_panel=_READ)
]
DepthOpt = Annotated[
    str | None,
    typer.Option("--depth", help="Depth topic registered to colour.", rich_help_panel=_READ),
]
InfoOpt = Annotated[
    str | None,
    typer.Option(
        "--camera-info", help="CameraInfo topic of the colour camera.", rich_help_panel=_READ
    ),
]
PoseOpt = Annotated[
    str | None,
    typer.Option(
        "--pose-source",
        help="Odometry or PoseStamped topic giving the pose (default: TF).",
        rich_help_panel=_READ,
    ),
]
WorldOpt = Annotated[
    str | None,
    typer.Option(
        "--world-frame",
        help="TF world frame (default map/world/odom or the TF root).",
        rich_help_panel=_READ,
    ),
]
CameraOpt = Annotated[
    str | None,
    typer.Option(
        "--camera-frame",
        help="Optical frame of the colour camera (x right, y down, z forward).",
        rich_help_panel=_READ,
    ),
]
MaxDtOpt = Annotated[
    float,
    typer.Option(
        "--max-dt", help="Seconds allowed between colour and depth stamps.", rich_help_panel=_READ
    ),
]
StaticOpt = Annotated[
    bool,
    typer.Option(
        "--static-pose",
        help="Identity pose for every frame (recordings without poses).",
        rich_help_panel=_READ,
    ),
]


def ingest(
    recording: Annotated[Path, typer.Argument(help="MCAP file, rosbag2 directory or ROS 1 .bag.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Store directory to write.")],
    encoder: Annotated[
        EncoderName | None,
        typer.Option("--encoder", help="Feature encoder; none = no features."),
    ] = None,
    weights: Annotated[
        str | None, typer.Option("--weights", help="Encoder weights directory or checkpoint id.")
    ] = None,
    precomputed: Annotated[
        Path | None,
        typer.Option("--precomputed", help="Parquet of per-view features (precomputed encoder)."),
    ] = None,
    device: Annotated[
        str | None, typer.Option("--device", help="torch device (default CUDA if available).")
    ] = None,
    batch_size: Annotated[
        int, typer.Option("--batch-size", help="Views per encoder batch.", min=1)
    ] = 8,
    perception: Annotated[
        Perception,
        typer.Option("--perception", help="Perception preset of the labels encoder."),
    ] = "default",  # type: ignore[assignment]
    seed: Annotated[
        int, typer.Option("--seed", help="Seed of the labels encoder's biases and noise.")
    ] = 0,
    vocabulary: Annotated[
        str | None,
        typer.Option(
            "--vocabulary",
            help="Class names whose text embeddings to cache: a bundled vocabulary name, a "
            "file, or comma-separated names.",
        ),
    ] = None,
    rrd: Annotated[
        Path | None, typer.Option("--rrd", help="Write a Rerun recording of the ingest.")
    ] = None,
    rrd_every: Annotated[
        int, typer.Option("--rrd-every", help="Log the point cloud of every Nth frame.", min=1)
    ] = 10,
    force: Annotated[
        bool, typer.Option("--force", help="Rebuild even if the store is up to date.")
    ] = False,
    rgb: RgbOpt = None,
    depth: DepthOpt = None,
    camera_info: InfoOpt = None,
    pose_source: PoseOpt = None,
    world_frame: WorldOpt = None,
    camera_frame: CameraOpt = None,
    max_dt: MaxDtOpt = 0.02,
    static_pose: StaticOpt = False,
    start: Annotated[
        float | None, typer.Option(help="Skip the frames of the first START seconds.")
    ] = None,
    end: Annotated[
        float | None, typer.Option(help="Stop reading END seconds after the first frame.")
    ] = None,
    every: Annotated[int, typer.Option(help="Keep every Nth frame of the time range.")] = 1,
    min_motion: Annotated[
        float,
        typer.Option(help="Skip frames that moved less than this (m) from the last one kept ..."),
    ] = 0.0,
    min_rotation: Annotated[
        float, typer.Option(help="... and turned less than this (degrees).")
    ] = 0.0,
) -> None:
    """Read a robot recording into a feature store (views, poses, features)."""
    from care.encoders import EncoderOptions
    from care.store import Store
    from ingest.pipeline import IngestConfig, run_ingest
    from ingest.select import FrameSelection

    config = IngestConfig(
        recording=recording,
        out=out,
        read=_read_options(
            rgb, depth, camera_info, pose_source, world_frame, camera_frame, max_dt, static_pose
        ),
        encoder=None if encoder is None else EncoderName(encoder).value,
        encoder_options=EncoderOptions(
            weights=weights,
            device=device,
            batch_size=batch_size,
            precomputed=precomputed,
            perception=Perception(perception).value,
            seed=seed,
        ),
        select=FrameSelection(start, end, every, min_motion, min_rotation),
        vocabulary=vocabulary,
        rrd=rrd,
        rrd_every=rrd_every,
        force=force,
    )
    path = run_ingest(config)
    store = Store(path)
    counts = store.meta.counts
    dropped = counts.get("dropped") or {}
    skipped = counts.get("skipped") or {}
    typer.echo(
        f"{path}: {store.num_views} views from {counts.get('rgb_messages', '?')} colour images"
        + (f", dropped {dropped}" if dropped else "")
        + (f", skipped {skipped}" if skipped else "")
    )


def topics(
    recording: Annotated[Path, typer.Argument(help="MCAP file, rosbag2 directory or ROS 1 .bag.")],
    rgb: RgbOpt = None,
    depth: DepthOpt = None,
    camera_info: InfoOpt = None,
    pose_source: PoseOpt = None,
    world_frame: WorldOpt = None,
    camera_frame: CameraOpt = None,
    max_dt: MaxDtOpt = 0.02,
    static_pose: StaticOpt = False,
    stamps: Annotated[
        bool,
        typer.Option(
            "--stamps",
            help="Print only the stamps (ns) of the colour images ingest would keep, one a "
            "line: the keys of a --precomputed features file.",
        ),
    ] = False,
) -> None:
    """List a recording's topics, types and counts, and what ingest would pick."""
    from care.errors import CareError
    from ingest.readers import open_reader
    from ingest.source import RecordingFrames

    if stamps:
        options = _read_options(
            rgb, depth, camera_info, pose_source, world_frame, camera_frame, max_dt, static_pose
        )
        with RecordingFrames(recording, options) as frames:
            for frame in frames:
                typer.echo(str(frame.stamp_ns))
        return

    with open_reader(recording) as reader:
        listed = reader.topics()
    width = max((len(n) for n in listed), default=0)
    for info in listed.values():
        typer.echo(f"{info.name:<{width}}  {info.msgtype:<36} {info.count:>7}")
    options = _read_options(
        rgb, depth, camera_info, pose_source, world_frame, camera_frame, max_dt, static_pose
    )
    try:
        with RecordingFrames(recording, options) as frames:
            chosen = frames.describe()
    except CareError as err:
        typer.echo(f"auto-detection: {err}")
        raise typer.Exit(1) from err
    sel = chosen["topics"]
    typer.echo("ingest would use:")
    for role in ("rgb", "depth", "camera_info", "pose_source", "class_names"):
        typer.echo(f"  {role:<12} {sel[role]}")
    typer.echo(f"  {'tf':<12} {', '.join(sel['tf']) or None}")
    typer.echo(f"  {'extras':<12} {sel['extras'] or None}")
    typer.echo(f"  world frame  {chosen['world_frame']}, camera frame {chosen['camera_frame']}")


def register(app: typer.Typer) -> None:
    """Add ``ingest`` and ``topics`` to ``app``."""
    app.command("ingest")(ingest)
    app.command("topics")(topics)
