"""``care explore STORE --views N``: where to look again, as goals a robot stack reads.

The options are generated from :class:`care_maps.query.explore.ExploreConfig` (what is proposed),
:class:`care_maps.query.goals.GoalConfig` (the robot's clearance, the goals' frame) and
:class:`care_maps.query.paths.PathConfig` (where the robot starts); the work is
:func:`care_maps.query.explore_store.explore_store`, the drawing :mod:`care_maps.query.explore_viz`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import typer

from care_maps.cli.options import Options, config_options, point_xy
from care_maps.query.explore import ExploreConfig
from care_maps.query.goals import GoalConfig
from care_maps.query.paths import PathConfig

__all__ = ["register"]

_FROM = {"start": {"flags": ("--from",)}}
_VIEWS = {"views": {"min": 1}, "contest_k": {"min": 1}}


@config_options("path", PathConfig, only=("start",), extra=_FROM, parse={"start": point_xy})
@config_options("goal", GoalConfig, only=("clearance", "frame_id"))
@config_options("settings", ExploreConfig, extra=_VIEWS)
def explore(
    store: Annotated[Path, typer.Argument(help="Store directory with a grid (`care fuse grid`).")],
    settings: Options[ExploreConfig] = None,  # type: ignore[assignment]
    goal: Options[GoalConfig] = None,  # type: ignore[assignment]
    path: Options[PathConfig] = None,  # type: ignore[assignment]
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print JSON: each view's goal and camera pose (geometry_msgs/PoseStamped), "
            "target and distance, and the goals alone in order.",
        ),
    ] = False,
    rrd: Annotated[
        Path | None,
        typer.Option(
            help="Write a Rerun recording: the map, its uncertainty and the proposed cameras."
        ),
    ] = None,
) -> None:
    """Propose --views camera poses in free space that look at what the grid map is least
    sure of (classes whose best candidates disagree, high entropy, pwKL or stderr, few
    views), reachable from --from (default: the recording's first pose) with --clearance.
    Needs no ground truth. Each view is a goal on the floor facing its target and the camera
    pose that sees it, in the frame `care frame` prints."""
    from care_maps.core.outputs import check_file_output, write_atomic
    from care_maps.query.explore_store import explore_store

    if rrd is not None:  # before the work: a file that is not ours is never replaced
        check_file_output(rrd, inputs=[store])
    found = explore_store(store, settings.config(), goal.config(), path.config())
    if rrd is not None:
        from care_maps.query.explore_viz import log_exploration

        write_atomic(rrd, lambda tmp: log_exploration(store, found, tmp))
    if as_json:
        typer.echo(json.dumps(found.as_dict()))
        return
    _table(found)
    if rrd is not None:
        typer.echo(f"wrote {rrd}")


def _table(found) -> None:
    """The views as a table on stdout."""
    answer = found.as_dict()
    views = answer["views"]
    frame = found.goals[0].frame_id if found.goals else "-"
    typer.echo(
        f"{len(views)} of {answer['requested']} views over {found.cmap.num_candidates} grid "
        f"cells (camera at {found.camera_height:.2f} m; uncertainty: "
        f"{', '.join(answer['measures'])})"
    )
    goal_column = f"goal in {frame!r} (x, y, yaw deg)"
    width = len(goal_column) + 1
    typer.echo(
        f"rank  target (x, y, z)        class            uncert.  covered  "
        f"{goal_column} pitch  path m"
    )
    for v in views:
        pose = v["goal"]["pose_stamped"]["pose"]["position"]
        dist = "-" if v["distance"] is None else f"{v['distance']:.2f}"
        target = "(" + ", ".join(f"{c:.2f}" for c in v["target"]) + ")"
        where = f"({pose['x']:.2f}, {pose['y']:.2f}, {math.degrees(v['goal']['yaw']):.0f})"
        typer.echo(
            f"{v['rank']:>4}  {target:<22} {str(v['target_class'])[:16]:<16} "
            f"{v['target_uncertainty']:>7.3f} {v['covered']:>8.1f}  {where:<{width}}"
            f"{v['pitch_deg']:>5.0f}  {dist}"
        )
    if len(views) < answer["requested"]:
        typer.echo(
            "fewer views than asked: no other uncertain place can be seen from free space "
            "within --max-range (and --spacing of the others)"
        )
    if answer["path_note"]:
        typer.echo(answer["path_note"])


def register(app: typer.Typer) -> None:
    """Add ``care explore`` to ``app``."""
    app.command("explore")(explore)
