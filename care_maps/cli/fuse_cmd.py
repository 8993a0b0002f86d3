"""``care fuse grid`` and ``care fuse instances``: maps from a feature store.

The map options are generated from :class:`care_maps.fuse.config.GridConfig` and
:class:`care_maps.fuse.config.InstanceConfig` (what shapes the map), the others from
:class:`care_maps.runtime.execution.Execution` (how the build runs) (:mod:`care_maps.cli.options`): one
default and one help text each. A map option not given takes the value the store's map was
built with (recorded in its table's metadata), so re-running a command does not rebuild a
map another command made. The stage modules are imported inside the commands so
``care --help`` stays fast.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer

from care_maps.cli.options import Options, config_options, with_choices
from care_maps.core.mapframe import UpAxis
from care_maps.fuse.config import GridConfig, InstanceConfig
from care_maps.fuse.keys import recorded_settings
from care_maps.runtime.execution import Execution

__all__ = ["register"]

StoreArg = Annotated[Path, typer.Argument(help="Feature store directory written by `care ingest`.")]
RrdOpt = Annotated[
    Path | None,
    typer.Option("--rrd", help="Also log the map to this Rerun file (open with `rerun FILE`)."),
]


def _recompute_help(source: str) -> str:
    return f"Only recompute the columns for --vocabulary / --logit-scale from {source}."


GridRecomputeOpt = Annotated[
    bool,
    typer.Option(
        help=_recompute_help(
            "the store's views (the grid's settings as built; the same columns as a rebuild)"
        )
    ),
]
InstancesRecomputeOpt = Annotated[
    bool, typer.Option(help=_recompute_help("instance_views.parquet"))
]


fuse_app = typer.Typer(
    help="Build maps (grid, instances) from a feature store.",
    no_args_is_help=True,
    rich_markup_mode=None,
)


UpAxisOpt = Annotated[
    UpAxis | None,
    typer.Option(
        help=with_choices(
            "Which world axis points up (auto: from the floor plane). Default: the frame the "
            "store already has, found automatically at its first fusion.",
            UpAxis,
        ),
        case_sensitive=False,
    ),
]
FloorOpt = Annotated[
    float | None,
    typer.Option(help="Floor height (m) along the up axis; default: measured from the depth."),
]


@contextlib.contextmanager
def _map_frame(store: Path, up_axis: UpAxis | None, floor_z: float | None) -> Iterator[None]:
    """Find the store's map frame anew when asked (the build in the block then uses it) and
    say it; put the old one back if the block fails."""
    from care_maps.fuse.frame import reframed

    if up_axis is None and floor_z is not None:
        up_axis = UpAxis.AUTO
    with reframed(store, up_axis, floor_z) as frame:
        typer.echo(frame.describe())
        yield


def _bytes(value: str) -> int:
    """``8G``, ``512M``, ``1.5GiB`` or a plain number of bytes."""
    from care_maps.core.errors import FuseError

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


def _vocabulary(value: str) -> tuple[str, ...]:
    from care_maps.core.vocab import vocabulary_option

    return vocabulary_option(value)


_REBUILD = {"overwrite": {"help": "Rebuild even if an up-to-date map exists."}}


def _recompute_args(settings: Options, config: Any) -> tuple[Any, float | None]:
    """``(vocabulary, logit_scale)`` of a ``--recompute``: None, the map's own, where not given."""
    given = settings.given
    return (
        config.vocabulary if "vocabulary" in given else None,
        config.logit_scale if "logit_scale" in given else None,
    )


def _recorded(store: Path, table: str, kind: str) -> bytes | None:
    """The settings the store's ``kind`` map was built with (None: no such map, or none
    recorded: :func:`care_maps.fuse.keys.recorded_settings`)."""
    import pyarrow.parquet as pq

    try:
        md = pq.read_schema(store / f"{table}.parquet").metadata or {}
    except (OSError, ValueError):  # no map yet, or a damaged one that the build replaces
        return None
    return recorded_settings(md, kind)


@fuse_app.command("grid")
@config_options(
    "run",
    Execution,
    only=("overwrite", "memory_budget", "read_ahead", "growth_state"),
    parse={"memory_budget": _bytes},
    extra=_REBUILD,
)
@config_options("settings", GridConfig, parse={"vocabulary": _vocabulary})
def grid(
    store: StoreArg,
    settings: Options[GridConfig],
    run: Options[Execution],
    recompute: GridRecomputeOpt = False,
    rrd: RrdOpt = None,
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
    the store's gravity-aligned map frame (z up, floor at 0), also written as map.pgm/.yaml.

    Settings not given are those the store's grid was built with (so a map made by
    `care run` is not rebuilt), else the defaults shown."""
    from care_maps.fuse import fuse_grid
    from care_maps.fuse.recompute import recompute_grid
    from care_maps.fuse.viz_grid import log_grid

    # options checked (GridConfig.__post_init__, Execution.__post_init__) before any work
    config = settings.config(_recorded(store, "cells", "grid"))
    how = run.config()
    with _writing(store, rrd), _map_frame(store, up_axis, floor_z):
        if recompute:
            path = recompute_grid(store, *_recompute_args(settings, config), run=how)
        else:
            path = fuse_grid(store, config, run=how)
        if rrd is not None:
            log_grid(store, rrd, target=rrd_class)
    _summary(path)
    from care_maps.cli.summary import frame_line

    typer.echo(frame_line(store))
    if rrd is not None:
        typer.echo(f"rerun {rrd}")


def _writing(store: Path, rrd: Path | None) -> Any:
    """Refuse a --rrd that is not ours, then hold the store's lock while its maps are written."""
    from care_maps.core.outputs import check_file_output, output_lock
    from care_maps.core.store import Store

    Store(store)  # a complete, undamaged store, or one line saying what to do
    if rrd is not None:
        check_file_output(rrd, inputs=[store])
    return output_lock(store)


def _summary(path: Path) -> None:
    from care_maps.core.store import read_table

    table = read_table(path, ["num_views"])
    views = table.column("num_views").to_numpy()
    typer.echo(f"{path}: {table.num_rows} candidates, {int((views >= 2).sum())} seen from 2+ views")


@fuse_app.command("instances")
@config_options("run", Execution, only=("batch_size", "read_ahead", "overwrite"), extra=_REBUILD)
@config_options("settings", InstanceConfig, parse={"vocabulary": _vocabulary})
def instances(
    store: StoreArg,
    settings: Options[InstanceConfig],
    run: Options[Execution],
    recompute: InstancesRecomputeOpt = False,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Any InstanceConfig field as FIELD=VALUE (repeatable), e.g. --set cluster_eps=0.1.",
        ),
    ] = None,
    rrd: RrdOpt = None,
    up_axis: UpAxisOpt = None,
    floor_z: FloorOpt = None,
) -> None:
    """Build the OpenMask3D-style instance map (instances.parquet), in the store's
    gravity-aligned map frame.

    Settings not given are those the store's instance map was built with, else the
    defaults shown."""
    from care_maps.fuse import fuse_instances
    from care_maps.fuse.instances import recompute_instances

    # options checked (InstanceConfig.__post_init__) before any work
    config = settings.config(
        _recorded(store, "instances", "instances"),
        **_field_values(InstanceConfig, set_ or []),
    )
    how = run.config()
    with _writing(store, rrd), _map_frame(store, up_axis, floor_z):
        if recompute:
            path = recompute_instances(store, *_recompute_args(settings, config))
        else:
            path = fuse_instances(store, config, run=how)
        if rrd is not None:
            from care_maps.fuse.viz_instances import log_instances

            log_instances(store, rrd)
    _summary(path)
    _proposal_quality(store)
    if rrd is not None:
        typer.echo(f"rerun {rrd}")


def _proposal_quality(store: Path) -> None:
    """Print how well the masks match the ground truth, when the source recording has one
    (sample-world recordings): the figure to check before trusting any retrieval result."""
    from care_maps.core.store import Store, source_recording
    from care_maps.fuse.evaluate_proposals import instance_map_iou
    from care_maps.truth.formats.native import gt_paths

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
    from care_maps.core.errors import FuseError

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
