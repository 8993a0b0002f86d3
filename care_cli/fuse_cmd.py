"""``care fuse grid`` and ``care fuse instances``: maps from a feature store.

Options mirror the frozen config dataclasses of :mod:`fuse.grid` and :mod:`fuse.instances`;
the stage modules are imported inside the commands so ``care --help`` stays fast.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Any

import typer

__all__ = ["register"]

StoreArg = Annotated[Path, typer.Argument(help="Feature store directory written by `care ingest`.")]
RrdOpt = Annotated[
    Path | None,
    typer.Option("--rrd", help="Also log the map to this Rerun file (open with `rerun FILE`)."),
]
VocabOpt = Annotated[
    str | None,
    typer.Option(
        "--vocabulary", help="Comma-separated class names (default: the store's cached names)."
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


def _vocabulary(value: str | None) -> tuple[str, ...] | None:
    if value is None:
        return None
    return tuple(name.strip() for name in value.split(",") if name.strip())


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
    rrd_class: Annotated[
        str | None,
        typer.Option(
            "--rrd-class",
            help="Class of the confidence layer in --rrd (default: the most frequent object class).",
        ),
    ] = None,
) -> None:
    """Fuse every view's dense features into occupied top-down cells (cells.parquet)."""
    from fuse.grid import GridConfig, build_grid
    from fuse.recompute import recompute_grid
    from fuse.viz_grid import log_grid

    if recompute:
        path = recompute_grid(store, _vocabulary(vocabulary), logit_scale)
    else:
        config = GridConfig(
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
        )
        path = build_grid(store, config)
    if rrd is not None:
        log_grid(store, rrd, target=rrd_class)
    _summary(path)
    if rrd is not None:
        typer.echo(f"rerun {rrd}")


def _summary(path: Path) -> None:
    from care.store import read_table

    table = read_table(path, ["num_views"])
    views = table.column("num_views").to_numpy()
    typer.echo(f"{path}: {table.num_rows} candidates, {int((views >= 2).sum())} seen from 2+ views")


@fuse_app.command("instances")
def instances(
    store: StoreArg,
    proposals: Annotated[
        str,
        typer.Option(
            help="Proposal method: geometric (planes removed, DBSCAN) or labels (oracle)."
        ),
    ] = "geometric",
    features: Annotated[
        str,
        typer.Option(
            help="Per-view feature: masked (pooled dense features) or crops (re-encoded)."
        ),
    ] = "masked",
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
) -> None:
    """Build the OpenMask3D-style instance map (instances.parquet)."""
    from fuse.instances import InstanceConfig, build_instances, recompute_instances

    if recompute:
        path = recompute_instances(store, _vocabulary(vocabulary), logit_scale)
        if rrd is not None:
            from fuse.viz_instances import log_instances

            log_instances(store, rrd)
    else:
        config = InstanceConfig(
            proposals=proposals,
            features=features,
            voxel_size=voxel_size,
            stride=stride,
            top_k=top_k,
            logit_scale=logit_scale,
            vocabulary=_vocabulary(vocabulary),
            overwrite=overwrite,
            **_field_values(InstanceConfig, set_ or []),
        )
        path = build_instances(store, config, rrd=rrd)
    _summary(path)
    _proposal_quality(store)
    if rrd is not None:
        typer.echo(f"rerun {rrd}")


def _proposal_quality(store: Path) -> None:
    """Print how well the masks match the ground truth, when the source recording has one
    (sample-world recordings): the figure to check before trusting any retrieval result."""
    from care.store import Store
    from fuse.evaluate_proposals import instance_map_iou
    from world.groundtruth import gt_paths

    source = (Store(store).meta.get("source") or {}).get("path")
    if not source or not gt_paths(Path(source))[1].is_file():
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
