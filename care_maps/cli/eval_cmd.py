"""``care eval``: every strategy's success on a dataset's queries, against ground truth.

The options are generated from :class:`care_maps.evaluate.config.EvalConfig` (what is made)
and :class:`care_maps.runtime.execution.Execution` (how it runs: workers, Ray); the ground
truth's options and the runner's are shared with ``care run`` (:mod:`care_maps.cli.run_cmd`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from care_maps.cli.options import Options, config_options, with_choices
from care_maps.evaluate.config import EvalConfig
from care_maps.runtime.execution import Backend, Execution
from care_maps.truth.load import GtFormat

__all__ = ["register"]

RayOpt = Annotated[
    bool,
    typer.Option(
        "--ray",
        help="Run as Ray tasks (care run: each recording's ingest and maps, then the "
        "evaluation; care eval: the scenes), on a local Ray unless --ray-address.",
    ),
]
_RAY_ADDRESS = {"help": "Address of a running Ray cluster, e.g. ray://head:10001 (implies --ray)."}

GT_FORMATS_HELP = (
    "Ground truth formats (see docs/evaluation.md): native (<rec>.gt.json + .gt.parquet), annotations "
    "(JSON/YAML/CSV boxes: class, cx, cy, cz, sx, sy, sz[, yaw][, room]), ply (labelled PLY: "
    "vertex instance + label, <name>.classes.json beside), scannet (<scene>_vh_clean_2.ply, "
    ".aggregation.json, _vh_clean_2.0.010000.segs.json), matterport (house folder: "
    "region_segmentations/ + house_segmentations/*.house), replica (mesh_semantic.ply + "
    "info_semantic.json)."
)
GtOpt = Annotated[
    list[Path] | None,
    typer.Option(
        "--gt",
        help="Ground truth file or folder of each recording/store, in order (repeat the option); "
        "default: named in index.json ('gt') or found beside the recording by name.",
    ),
]
GtFormatOpt = Annotated[
    GtFormat | None,
    typer.Option(
        help=with_choices("Format of the ground truth (default: detected).", GtFormat),
        case_sensitive=False,
    ),
]
GtTransformOpt = Annotated[
    str | None,
    typer.Option(
        help="4x4 taking the ground truth's frame to the map frame: 16 numbers (row-major, "
        "comma-separated) or a file (.npy, .json, text, ScanNet's axisAlignment)."
    ),
]
GtClassMapOpt = Annotated[
    str | None,
    typer.Option(
        help="Rename ground-truth classes: a two-column file (from, to; empty 'to' drops) or "
        "TSV:FROM:TO, e.g. scannetv2-labels.combined.tsv:raw_category:nyu40class."
    ),
]


def _gt_defaults(fmt: str | None, transform: str | None, class_map: str | None):
    from care_maps.evaluate.groundtruth import GtSource

    return GtSource.of(None, fmt, transform, class_map)


def _execution(options: Options[Execution], ray: bool) -> Execution:
    """How the command runs: on Ray with ``--ray`` or ``--ray-address`` (a cluster at that
    address, else a local Ray), otherwise in local processes (``--workers 0``: one per CPU)."""
    values = options.values
    ray = ray or bool(values["ray_address"])
    return options.config(
        backend=Backend.RAY if ray else Backend.PROCESSES,
        **({"workers": None} if values["workers"] == 0 else {}),
    )


_GT_UNKNOWN = {"unknown_classes": "gt_unknown_classes"}


@config_options(
    "run",
    Execution,
    only=("workers", "ray_address"),
    extra={"workers": {"min": 0, "help": "Local processes (0: one per CPU)."},
           "ray_address": _RAY_ADDRESS},
)  # fmt: skip
@config_options("settings", EvalConfig, names=_GT_UNKNOWN)
def eval_(
    dataset: Annotated[
        list[Path],
        typer.Argument(
            help="Dataset directory (index.json of recordings with fused stores) or stores. "
            + GT_FORMATS_HELP
        ),
    ],
    out: Annotated[
        Path, typer.Option(help="Output directory (results.md, Parquet, plots).")
    ] = Path("out/eval"),
    settings: Options[EvalConfig] = None,  # type: ignore[assignment]
    run: Options[Execution] = None,  # type: ignore[assignment]
    ray: RayOpt = False,
    gt: GtOpt = None,
    gt_format: GtFormatOpt = None,
    gt_transform: GtTransformOpt = None,
    gt_class_map: GtClassMapOpt = None,
) -> None:
    """Success of every strategy on every (scene, class) query; writes the paper's tables
    and the paired comparisons.

    Ground truth formats: native, annotations (JSON/YAML/CSV boxes), ply (labelled PLY),
    scannet, matterport, replica; see --gt and docs/evaluation.md."""
    from care_maps.evaluate import evaluate

    config = settings.config()
    report = evaluate(
        dataset, config, out, run=_execution(run, ray),
        gt=tuple(gt or ()), gt_defaults=_gt_defaults(gt_format, gt_transform, gt_class_map),
    )  # fmt: skip
    typer.echo(report.markdown)
    typer.echo(f"wrote {out}/results.md, attempts.parquet, summary.parquet and plots/")


def register(app: typer.Typer) -> None:
    """Add ``care eval`` to ``app``."""
    app.command("eval")(eval_)
