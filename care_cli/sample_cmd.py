"""``care sample make``: procedural sample-world recordings with ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

__all__ = ["register"]

sample_app = typer.Typer(
    name="sample",
    help="Procedural sample world: scenes with ground truth, rendered into real recordings.",
    no_args_is_help=True,
)


@sample_app.command("make")
def make(
    out: Annotated[Path, typer.Option("--out", help="Dataset directory to create or complete.")],
    scenes: Annotated[int, typer.Option("--scenes", help="Number of scenes.")] = 1,
    seed: Annotated[int, typer.Option("--seed", help="Dataset seed.")] = 0,
    fmt: Annotated[
        str, typer.Option("--format", help="Recording format: mcap, ros2 (rosbag2 dir) or ros1.")
    ] = "mcap",
    width: Annotated[int, typer.Option("--width", help="Image width in pixels.")] = 640,
    height: Annotated[int, typer.Option("--height", help="Image height in pixels.")] = 480,
    frames: Annotated[
        int | None, typer.Option("--frames", help="Frames per recording (default 25 per room).")
    ] = None,
    rooms: Annotated[
        int | None, typer.Option("--rooms", help="Rooms per scene, 1-6 (default 2-5, drawn).")
    ] = None,
    jpeg: Annotated[
        bool, typer.Option("--jpeg/--raw", help="JPEG CompressedImage colour, or raw rgb8.")
    ] = False,
    workers: Annotated[int, typer.Option("--workers", help="Parallel processes.")] = 2,
    rrd: Annotated[
        Path | None,
        typer.Option("--rrd", help="Also write a Rerun recording of the scenes (meshes, boxes)."),
    ] = None,
    gt_formats: Annotated[
        str,
        typer.Option(
            "--gt-formats",
            help="Ground truth formats to write beside each recording (comma-separated): native, "
            "json, yaml, csv, ply, scannet, matterport, replica, or all.",
        ),
    ] = "native",
) -> None:
    """Generate scenes, render an exploration of each, write recordings + ground truth + index.json."""
    from care.errors import WorldError
    from world.record import DatasetConfig, make_dataset

    if fmt not in ("mcap", "ros2", "ros1"):
        msg = f"--format {fmt!r}: choose mcap, ros2 or ros1"
        raise WorldError(msg)
    from truth.load import EXPORT_FORMATS

    formats = tuple(f.strip() for f in gt_formats.split(",") if f.strip())
    unknown = sorted(set(formats) - {*EXPORT_FORMATS, "all"})
    if unknown:
        msg = f"--gt-formats {','.join(unknown)}: choose from {', '.join(EXPORT_FORMATS)} or all"
        raise WorldError(msg)
    index = make_dataset(
        DatasetConfig(
            out=out,
            scenes=scenes,
            seed=seed,
            fmt=fmt,  # type: ignore[arg-type]
            width=width,
            height=height,
            frames=frames,
            num_rooms=rooms,
            compressed_rgb=jpeg,
            workers=workers,
            rrd=rrd,
        )
    )
    if set(formats) - {"native"}:
        from truth.load import export_ground_truth
        from world.dataset_index import read_index
        from world.groundtruth import GroundTruth

        for entry in read_index(index.parent):
            chosen = EXPORT_FORMATS if "all" in formats else formats
            others = [f for f in chosen if f != "native"]  # make_dataset wrote the native files
            export_ground_truth(GroundTruth.load(entry.recording), entry.recording, others)
    typer.echo(f"wrote {index}")


def register(app: typer.Typer) -> None:
    """Add ``care sample ...`` to ``app``."""
    app.add_typer(sample_app, name="sample")
