"""``care sample make``: procedural sample-world recordings with ground truth.

Its dataset options are generated from :class:`care_maps.world.record.DatasetConfig`
(:mod:`care_maps.cli.options`): each default and help text exists once, in the dataclass.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer

from care_maps.cli.options import Options, config_options
from care_maps.core.errors import WorldError
from care_maps.ingest.formats import RecordingFormat
from care_maps.world.record import DatasetConfig

__all__ = ["register"]

sample_app = typer.Typer(
    name="sample",
    help="Procedural sample world: scenes with ground truth, rendered into real recordings.",
    no_args_is_help=True,
    rich_markup_mode=None,
)


def _format(value: str) -> RecordingFormat:
    """``--format``'s value; anything else is refused in one line that lists the formats."""
    try:
        return RecordingFormat(value)
    except ValueError as err:
        msg = f"--format {value!r}: choose {RecordingFormat.choices()}"
        raise WorldError(msg) from err


@sample_app.command("make")
@config_options(
    "dataset",
    DatasetConfig,
    skip=("world", "progress"),
    names={"fmt": "format", "num_rooms": "rooms"},
    parse={"fmt": _format},
    extra={
        "out": {"flags": ("--out",)},
        "compressed_rgb": {"flags": ("--jpeg/--raw",)},
        "preset": {"help": "World and perception preset: default (the sample world), "
                   "matterport-like (229 classes, ~25 instances per room, first attempts near "
                   "the paper's), matterport-clip (the same with CLIP-like image-text "
                   "similarities), ideal."},
    },
)  # fmt: skip
def make(
    dataset: Options[DatasetConfig],
    gt_formats: Annotated[
        str,
        typer.Option(
            "--gt-formats",
            help="Ground truth formats to write beside each recording (comma-separated): native, "
            "json, yaml, csv, ply, scannet, matterport, replica, or all.",
        ),
    ] = "native",
    sets: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Change one knob of the preset: KEY=VALUE (repeatable). Keys: scene knobs "
            "(catalogue, clutter, instances_per_room, ...) and perception knobs "
            "(class_bias_rate, bias_noise_scale, view_bias_rate, ...; see docs/sample-world.md).",
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
    likeness: Annotated[
        bool,
        typer.Option(
            "--likeness/--no-likeness",
            help="Measure how CLIP-like the simulated features are on a few views of the "
            "first scene, against published targets (seconds; written to index.json and "
            "printed as a table).",
        ),
    ] = True,
) -> None:
    """Generate scenes, render an exploration of each, write recordings + ground truth + index.json."""
    from care_maps.world.presets import PRESETS, with_sets
    from care_maps.world.record import make_dataset

    preset = dataset.values["preset"]
    try:
        world = with_sets(PRESETS[preset], sets or ())
    except WorldError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from err

    from care_maps.truth.load import EXPORT_FORMATS

    formats = tuple(f.strip() for f in gt_formats.split(",") if f.strip())
    unknown = sorted(set(formats) - {*EXPORT_FORMATS, "all"})
    if unknown:
        msg = f"--gt-formats {','.join(unknown)}: choose from {', '.join(EXPORT_FORMATS)} or all"
        raise WorldError(msg)
    config = dataset.config(world=world)
    likeness_entry: dict = {}

    def finish(index: Path) -> None:
        """The rest of the work, on the staged dataset: it is swapped in whole with it."""
        if set(formats) - {"native"}:
            from care_maps.truth.dataset_index import read_index
            from care_maps.truth.formats.native import read_native
            from care_maps.truth.load import export_ground_truth

            for entry in read_index(index.parent):
                chosen = EXPORT_FORMATS if "all" in formats else formats
                others = [f for f in chosen if f != "native"]  # make_dataset wrote the native
                export_ground_truth(read_native(entry.recording), entry.recording, others)
        if measure:
            from care_maps.research.dataset_stats import measure_first_attempts

            measure_first_attempts(index.parent, workers=config.workers)
        if likeness:
            from care_maps.world.perception.likeness import record_likeness

            start = time.perf_counter()  # printed, never written: the same input, the same bytes
            likeness_entry.update(record_likeness(index.parent))
            likeness_entry["seconds"] = time.perf_counter() - start

    index = make_dataset(config, finish=finish)
    typer.echo(_statistics_line(index))
    if likeness:
        from care_maps.world.perception.likeness import likeness_table

        entry = likeness_entry
        typer.echo(
            f"CLIP likeness of {entry['recording']} ({entry['views']} views, "
            f"{entry['measured'].get('object_views', 0)} object segments, "
            f"{entry['seconds']:.1f} s):"
        )
        typer.echo(likeness_table(entry["measured"], markdown=False))
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
