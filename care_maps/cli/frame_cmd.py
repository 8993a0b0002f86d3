"""``care frame STORE``: the frame a store's goals and ``map.yaml`` are in, and how a robot
stack publishes it (:mod:`care_maps.query.publish`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from care_maps.cli.options import parsed
from care_maps.core.frames import check_frame_id

__all__ = ["register"]


def frame(
    store: Annotated[Path, typer.Argument(help="Store directory with a grid (`care fuse grid`).")],
    frame_id: Annotated[
        str | None,
        typer.Option(
            help="Name of the frame goals and map.yaml are in: the recording's world frame, "
            "or a name for the map frame to publish (default: the world frame when it has "
            "z up, else care_map). Give the same --frame-id to care query and care replan.",
            callback=parsed(check_frame_id),  # the check of every frame-id option
        ),
    ] = None,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json", help="Print the geometry_msgs/TransformStamped JSON to publish (or null)."
        ),
    ] = False,
) -> None:
    """Say which frame the store's goals and map.yaml are in, and print the commands that
    serve the map in it and, where that frame is not in the recording's TF tree, publish
    it as a static transform under the world frame."""
    from care_maps.core.store import Store
    from care_maps.query.goals import GoalMaker
    from care_maps.query.publish import (
        map_server_command,
        static_transform_command,
        transform_stamped,
    )

    Store(store)  # a complete store, or one line saying what to do
    plan = GoalMaker.plan(store, frame_id)
    if as_json:
        typer.echo(json.dumps(transform_stamped(plan) if plan.publish else None))
        return
    if plan.publish:
        typer.echo(
            f"goals and map.yaml are in frame {plan.frame_id!r}, the map frame (z up, floor at "
            f"0), which the recording's TF tree lacks; publish it under {plan.world_frame!r}:"
        )
        typer.echo(f"  {static_transform_command(plan)}")
    else:
        typer.echo(
            f"goals and map.yaml are in the recording's world frame {plan.world_frame!r} "
            "(z up: x and y are the map's); nothing to publish"
        )
    map_yaml = Path(store) / "map.yaml"
    if map_yaml.is_file():
        typer.echo(f"serve the map: {map_server_command(map_yaml, plan)}")
    else:
        typer.echo(f"no map.yaml yet: run `care fuse grid {store}`")


def register(app: typer.Typer) -> None:
    """Add ``care frame`` to ``app``."""
    app.command("frame")(frame)
