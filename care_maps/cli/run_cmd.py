"""``care run``: the main job, every stage chained (ingest, both maps, the evaluation) over
a recording, a folder of recordings or a dataset.

The options are generated from :class:`care_maps.evaluate.config.RunConfig` and the configs
of the stages it runs; the ground truth's and the runner's are ``care eval``'s
(:mod:`care_maps.cli.eval_cmd`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from care_maps.cli.choices import EncoderName
from care_maps.cli.eval_cmd import (
    _GT_UNKNOWN,
    _RAY_ADDRESS,
    GtClassMapOpt,
    GtFormatOpt,
    GtOpt,
    GtTransformOpt,
    RayOpt,
    _execution,
    _gt_defaults,
)
from care_maps.cli.ingest_cmd import read_options
from care_maps.cli.options import Options, config_options
from care_maps.core.encoders.base import EncoderOptions
from care_maps.evaluate.config import EvalConfig, RunConfig
from care_maps.ingest.select import FrameSelection
from care_maps.ingest.source import ReadOptions
from care_maps.runtime.execution import Execution

__all__ = ["register"]

_RUN = {
    "vocabulary": {
        "help": "Class names to embed: a bundled vocabulary name, a file, or "
        "comma-separated names (default: the recording's own class names)."
    }
}


@config_options("evaluation", EvalConfig,
                only=("attempts", "seeds", "unknown_classes", "travel_start"),
                names=_GT_UNKNOWN)  # fmt: skip
@config_options("run_options", Execution, only=("workers", "ray_address"),
                extra={"workers": {"min": 1}, "ray_address": _RAY_ADDRESS})  # fmt: skip
@config_options("settings", RunConfig, only=("encoder", "vocabulary", "rrd_ingest", "rrd_class"),
                extra={**_RUN, "encoder": {"type": EncoderName},
                       "rrd_class": {"flags": ("--rrd-class",)}})  # fmt: skip
@config_options("encoding", EncoderOptions, only=("weights", "precomputed"))
@read_options
@config_options("selection", FrameSelection)
def run(
    recording: Annotated[
        Path | None,
        typer.Argument(
            help="A recording, a folder of recordings (any mix of formats) or a dataset "
            "directory (index.json); default the bundled sample."
        ),
    ] = None,
    encoding: Options[EncoderOptions] = None,  # type: ignore[assignment]
    out: Annotated[Path, typer.Option(help="Output directory: stores, .rrd files, tables.")] = Path(
        "out"
    ),
    settings: Options[RunConfig] = None,  # type: ignore[assignment]
    run_options: Options[Execution] = None,  # type: ignore[assignment]
    evaluation: Options[EvalConfig] = None,  # type: ignore[assignment]
    read: Options[ReadOptions] = None,  # type: ignore[assignment]
    selection: Options[FrameSelection] = None,  # type: ignore[assignment]
    ray: RayOpt = False,
    gt: GtOpt = None,
    gt_format: GtFormatOpt = None,
    gt_transform: GtTransformOpt = None,
    gt_class_map: GtClassMapOpt = None,
) -> None:
    """The main job: ingest, fuse both maps, evaluate every strategy; print the table.

    Ground truth: beside each recording by name, named in index.json, or --gt (formats:
    native, annotations, ply, scannet, matterport, replica; see `care eval --help`). A
    recording without any gets its maps and Rerun files, and is not evaluated."""
    from care_maps.evaluate.pipeline import run_all

    config = settings.config(
        encoder_options=encoding.config(),
        read=read.config(),
        select=selection.config(),
        evaluation=evaluation.config(),
        gt=tuple(gt or ()),
        gt_defaults=_gt_defaults(gt_format, gt_transform, gt_class_map),
    )
    result = run_all(recording, out, config, run=_execution(run_options, ray))
    from care_maps.cli.summary import store_lines

    for store in result.stores:
        for line in store_lines(store):
            typer.echo(line)
    if result.unevaluated:
        typer.echo(
            f"no ground truth for {', '.join(result.unevaluated)}: maps and Rerun files made, "
            "not evaluated (docs/evaluation.md: Your own annotations)"
        )
    if result.report is not None:
        typer.echo(result.report.overview.rstrip())
        typer.echo(
            f"\nfull report (every rule and k, intervals, paired and SPL tests): "
            f"{out / 'eval' / 'results.md'} (its tables: {out / 'eval'}/*.parquet)"
        )
    typer.echo(f"stores: {', '.join(str(p) for p in result.stores)}")
    typer.echo(f"open the maps and every decision in Rerun:\n  {result.rerun_command()}")
    if result.failed:  # each was reported in one line as it failed; the others completed
        names = ", ".join(name for name, _ in result.failed)
        typer.echo(f"error: {len(result.failed)} recording(s) failed: {names}", err=True)
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add ``care run`` to ``app``."""
    app.command("run")(run)
