"""``care fuse grid`` and ``care fuse instances``: maps from a feature store.

Options mirror the frozen config dataclasses of :mod:`fuse.grid` and :mod:`fuse.instances`;
the stage modules are imported inside the commands so ``care --help`` stays fast.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Any

import typer

from care.mapframe import UpAxis
from care_cli.choices import InstanceFeatures, ProposalMethod

__all__ = ["register"]

StoreArg = Annotated[Path, typer.Argument(help="Feature store directory written by `care ingest`.")]
RrdOpt = Annotated[
    Path | None,
    typer.Option("--rrd", help="Also log the map to this Rerun file (open with `rerun FILE`)."),
]
VocabOpt = Annotated[
    str | None,
    typer.Option(
        "--vocabulary",
        help="A bundled vocabulary name, a file, or comma-separated class names (default: "
        "the store's cached names).",
    ),
]

LogitScaleOpt = Annotated[float, typer.Option(help="Scale s of softmax(s * f . t).")]
OverwriteOpt = Annotated[bool, typer.Option(help="Rebuild even if an up-to-date map exists.")]


def _recompute_opt(views_table: str) -> Any:
    return Annotated[
        bool,
        typer.Option(
            help=f"Only recompute the columns for --vocabulary / --logit-scale from {views_table}."
        ),
    ]


fuse_app = typer.Typer(
    help="Build maps (grid, instances) from a feature store.", no_args_is_help=True
)


UpAxisOpt = Annotated[
    UpAxis | None,
    typer.Option(
        help="Which world axis points up (auto: from the floor plane). Default: the frame the "
        "store already has, found automatically at its first fusion.",
        case_sensitive=False,
    ),
]
FloorOpt = Annotated[
    float | None,
    typer.Option(help="Floor height (m) along the up axis; default: measured from the depth."),
]


def _map_frame(store: Path, up_axis: UpAxis | None, floor_z: float | None) -> None:
    """Find the store's map frame anew when asked (a later build then uses it), and say it."""
    from fuse.frame import ensure_map_frame

    if up_axis is None and floor_z is not None:
        up_axis = UpAxis.AUTO
    typer.echo(ensure_map_frame(store, up_axis, floor_z).describe())


def _vocabulary(value: str | None) -> tuple[str, ...] | None:
    from care.vocab import vocabulary_option

    return None if value is None else vocabulary_option(value)


def _bytes(value: str) -> int:
    """``8G``, ``512M``, ``1.5GiB`` or a plain number of bytes."""
    from care.errors import FuseError

    units = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}
    text = value.strip().lower().removesuffix("ib").removesuffix("b")
    unit = text[-1:] if text[-1:] in units else ""
    try:
        amount = float(text[: len(text) - len(unit)])
    except ValueError:
        amount = -1.0
    if amount <= 0:
        msg = f"--memory-budget {value!r}: give a size such as 8G, 512M or a number of bytes"
        raise FuseError(msg)
    return int(amount * units[unit])


@fuse_app.command("grid")
def grid(
    store: StoreArg,
    cell_size: Annotated[float, typer.Option(help="Cell edge in metres.")] = 0.05,
    stride: Annotated[
        int, typer.Option(help="Use every stride-th depth pixel (1 = full resolution).")
    ] = 1,
    z_min: Annotated[float, typer.Option(help="Lowest world height (m) fused.")] = -0.2,
    z_max: Annotated[
        float, typer.Option(help="Highest world height (m) fused; keeps the ceiling out.")
    ] = 2.0,
    sigma_z: Annotated[float, typer.Option(help="Depth scale (m) of the distance weight.")] = 2.5,
    distance_weighting: Annotated[
        bool, typer.Option(help="Weight pixels by exp(-z^2 / (2 sigma_z^2)) (VLMaps).")
    ] = True,
    logit_scale: LogitScaleOpt = 100.0,
    vocabulary: VocabOpt = None,
    obstacle_height: Annotated[
        float, typer.Option(help="Height (m) above which a cell is an obstacle.")
    ] = 0.1,
    overwrite: OverwriteOpt = False,
    recompute: _recompute_opt("cell_views.parquet") = False,
    rrd: RrdOpt = None,
    memory_budget: Annotated[
        str | None,
        typer.Option(
            help="Memory the fusion may use, e.g. 8G or 512M (default: half of this machine's); "
            "a floor too large for it is fused in several passes over the views."
        ),
    ] = None,
    up_axis: UpAxisOpt = None,
    floor_z: FloorOpt = None,
    rrd_class: Annotated[
        str | None,
        typer.Option(
            "--rrd-class",
            help="Class of the confidence layer in --rrd (default: the most frequent object class).",
        ),
    ] = None,
) -> None:
    """Fuse every view's dense features into occupied top-down cells (cells.parquet), in
    the store's gravity-aligned map frame (z up, floor at 0), also written as map.pgm/.yaml."""
    from fuse.grid import GridConfig, build_grid
    from fuse.recompute import recompute_grid
    from fuse.viz_grid import log_grid

    config = GridConfig(  # options checked (GridConfig.__post_init__) before any work
        cell_size=cell_size,
        stride=stride,
        z_min=z_min,
        z_max=z_max,
        sigma_z=sigma_z,
        distance_weighting=distance_weighting,
        logit_scale=logit_scale,
        vocabulary=_vocabulary(vocabulary),
        obstacle_height=obstacle_height,
        overwrite=overwrite,
        memory_budget=None if memory_budget is None else _bytes(memory_budget),
    )
    with _writing(store, rrd):
        _map_frame(store, up_axis, floor_z)
        if recompute:
            path = recompute_grid(store, config.vocabulary, logit_scale)
        else:
            path = build_grid(store, config)
        if rrd is not None:
            log_grid(store, rrd, target=rrd_class)
    _summary(path)
    if rrd is not None:
        typer.echo(f"rerun {rrd}")


def _writing(store: Path, rrd: Path | None) -> Any:
    """Refuse a --rrd that is not ours, then hold the store's lock while its maps are written."""
    from care.outputs import check_file_output, output_lock
    from care.store import Store

    Store(store)  # a complete, undamaged store, or one line saying what to do
    if rrd is not None:
        check_file_output(rrd, inputs=[store])
    return output_lock(store)


def _summary(path: Path) -> None:
    from care.store import read_table

    table = read_table(path, ["num_views"])
    views = table.column("num_views").to_numpy()
    typer.echo(f"{path}: {table.num_rows} candidates, {int((views >= 2).sum())} seen from 2+ views")


@fuse_app.command("instances")
def instances(
    store: StoreArg,
    proposals: Annotated[
        ProposalMethod,
        typer.Option(
            help="Proposal method: geometric (planes removed, DBSCAN) or labels (oracle)."
        ),
    ] = "geometric",  # type: ignore[assignment]
    features: Annotated[
        InstanceFeatures,
        typer.Option(
            help="Per-view feature: masked (pooled dense features) or crops (re-encoded)."
        ),
    ] = "masked",  # type: ignore[assignment]
    voxel_size: Annotated[float, typer.Option(help="Voxel edge (m) of the scene cloud.")] = 0.03,
    stride: Annotated[int, typer.Option(help="Back-project every stride-th depth pixel.")] = 2,
    top_k: Annotated[int, typer.Option(help="Views kept per instance (OpenMask3D: 5).")] = 5,
    logit_scale: LogitScaleOpt = 100.0,
    vocabulary: VocabOpt = None,
    overwrite: OverwriteOpt = False,
    recompute: _recompute_opt("instance_views.parquet") = False,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Any other InstanceConfig field as FIELD=VALUE (repeatable), e.g. --set cluster_eps=0.1.",
        ),
    ] = None,
    rrd: RrdOpt = None,
    up_axis: UpAxisOpt = None,
    floor_z: FloorOpt = None,
) -> None:
    """Build the OpenMask3D-style instance map (instances.parquet), in the store's
    gravity-aligned map frame."""
    from fuse.instances import InstanceConfig, build_instances, recompute_instances

    config = InstanceConfig(  # options checked (InstanceConfig.__post_init__) before any work
        proposals=ProposalMethod(proposals).value,
        features=InstanceFeatures(features).value,
        voxel_size=voxel_size,
        stride=stride,
        top_k=top_k,
        logit_scale=logit_scale,
        vocabulary=_vocabulary(vocabulary),
        overwrite=overwrite,
        **_field_values(InstanceConfig, set_ or []),
    )
    with _writing(store, rrd):
        _map_frame(store, up_axis, floor_z)
        if recompute:
            path = recompute_instances(store, config.vocabulary, logit_scale)
            if rrd is not None:
                from fuse.viz_instances import log_instances

                log_instances(store, rrd)
        else:
            path = build_instances(store, config, rrd=rrd)
    _summary(path)
    _proposal_quality(store)
    if rrd is not None:
        typer.echo(f"rerun {rrd}")


def _proposal_quality(store: Path) -> None:
    """Print how well the masks match the ground truth, when the source recording has one
    (sample-world recordings): the figure to check before trusting any retrieval result."""
    from care.store import Store, source_recording
    from fuse.evaluate_proposals import instance_map_iou
    from world.groundtruth import gt_paths

    source = source_recording(store, Store(store).meta)
    if source is None or not gt_paths(source)[1].is_file():
        return
    ids, iou = instance_map_iou(store)
    typer.echo(
        f"proposals vs ground truth: mean best IoU {iou.mean():.3f} over {len(ids)} instances, "
        f"{int((iou > 0.5).sum())} above 0.5, {int((iou > 0.25).sum())} above 0.25"
        if len(ids)
        else "proposals vs ground truth: no ground-truth instance in the scene cloud"
    )


def _field_values(cls: Any, assignments: list[str]) -> dict[str, Any]:
    """``FIELD=VALUE`` strings for a frozen config dataclass, typed by the fields' defaults."""
    from care.errors import FuseError

    fields = {f.name: f for f in dataclasses.fields(cls)}
    out: dict[str, Any] = {}
    for item in assignments:
        name, sep, value = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or name not in fields:
            msg = f"--set {item!r}: expected FIELD=VALUE with FIELD one of {', '.join(fields)}"
            raise FuseError(msg)
        default = fields[name].default
        try:
            if isinstance(default, bool):
                out[name] = value.strip().lower() in ("1", "true", "yes", "on")
            elif isinstance(default, int | float):
                out[name] = type(default)(value)
            else:
                out[name] = value
        except ValueError as err:
            msg = f"--set {item!r}: {value!r} is not a {type(default).__name__}"
            raise FuseError(msg) from err
    return out


def register(app: typer.Typer) -> None:
    """Add the ``care fuse`` group to ``app``."""
    app.add_typer(fuse_app, name="fuse")
