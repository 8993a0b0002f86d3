"""``care sample make``: procedural sample-world recordings with ground truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from world.presets import WorldPreset

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
    preset: Annotated[
        WorldPreset,
        typer.Option(
            "--preset",
            help="World and perception preset: default (the sample world), matterport-like "
            "(229 classes, ~25 instances per room, first attempts near the paper's), ideal.",
        ),
    ] = WorldPreset.DEFAULT,
    sets: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Change one knob of the preset: KEY=VALUE (repeatable). Keys: scene knobs "
            "(catalogue, clutter, instances_per_room, ...) and perception knobs "
            "(class_bias_rate, bias_noise_scale, view_bias_rate, ...; see README).",
        ),
    ] = None,
    measure: Annotated[
        bool,
        typer.Option(
            "--measure/--no-measure",
            help="Also run the pipeline on the dataset and record the first-attempt success "
            "of each map (minutes; written to index.json and printed).",
        ),
    ] = False,
) -> None:
    """Generate scenes, render an exploration of each, write recordings + ground truth + index.json."""
    from care.errors import WorldError
    from world.presets import PRESETS, with_sets
    from world.record import DatasetConfig, make_dataset

    try:
        world = with_sets(PRESETS[preset], sets or ())
    except WorldError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from err

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
            preset=preset,
            world=world,
        )
    )
    if set(formats) - {"native"}:
        from truth.dataset_index import read_index
        from truth.load import export_ground_truth
        from truth.model import GroundTruth

        for entry in read_index(index.parent):
            chosen = EXPORT_FORMATS if "all" in formats else formats
            others = [f for f in chosen if f != "native"]  # make_dataset wrote the native files
            export_ground_truth(GroundTruth.load(entry.recording), entry.recording, others)
    if measure:
        from evaluate.dataset_stats import measure_first_attempts

        measure_first_attempts(index.parent, workers=workers)
    typer.echo(_statistics_line(index))
    typer.echo(f"wrote {index}")


def _statistics_line(index: Path) -> str:
    """One line of what the dataset holds (and its first attempts, once measured)."""
    doc = json.loads(Path(index).read_text())
    st = doc.get("statistics", {})
    per = st.get("instances_per_room", {})
    line = (
        f"{st.get('scenes')} scenes, {st.get('rooms')} rooms, {st.get('instances')} instances "
        f"({per.get('mean')} per room, {per.get('min')}-{per.get('max')}), "
        f"{st.get('classes')} classes ({st.get('classes_per_scene')} per scene)"
    )
    first = st.get("first_attempt")
    if first:
        line += "; first attempt " + ", ".join(f"{k} {v:.1f}%" for k, v in first.items())
    return line


def register(app: typer.Typer) -> None:
    """Add ``care sample ...`` to ``app``."""
    app.add_typer(sample_app, name="sample")
