"""What each stage found in a store, in the lines the single commands print: ``care run``
prints the same for every recording, so a batch run tells as much as the steps one by one."""

from __future__ import annotations

from pathlib import Path

__all__ = ["frame_line", "geometry_line", "ingest_line", "runs_lines", "store_lines"]


def ingest_line(store: Path) -> str:
    """Views kept of the colour images read, and what was dropped or skipped."""
    from care_maps.core.store import Store

    opened = Store(store)
    counts = opened.meta.counts
    dropped = counts.get("dropped") or {}
    skipped = counts.get("skipped") or {}
    return (
        f"{store}: {opened.num_views} views from {counts.get('rgb_messages', '?')} colour images"
        + (f", dropped {dropped}" if dropped else "")
        + (f", skipped {skipped}" if skipped else "")
    )


def geometry_line(store: Path) -> str | None:
    """What ingest's geometric consistency check found (None for a store made before it)."""
    from care_maps.core.store import Store
    from care_maps.ingest.consistency import describe_verdict

    found = Store(store).meta.geometry
    if not found:
        return None
    kept = " (kept as given: --accept-geometry)" if found.get("accepted") else ""
    return f"{store}: {describe_verdict(found)}{kept}"


def runs_lines(store: Path) -> list[str]:
    """One line per exploration run of a store that holds several (none for one run): its
    views, recording, frame and placement, and how it agreed with the runs before it."""
    from care_maps.core.store import Store
    from care_maps.ingest.runs import describe_alignment

    runs = Store(store).meta.runs
    lines = []
    for k, run in enumerate(runs, 1):
        views = run.view_ids
        line = (
            f"{store}: run {k} of {len(runs)}: views {views.start}-{views.stop - 1} from "
            f"{run.source.name} in world frame {run.world_frame!r}"
        )
        if run.world_transform is not None:
            placed = ",".join(f"{v:g}" for v in run.world_transform)
            line += f", placed by --world-transform {placed}"
        if run.alignment is not None:
            line += f"; {describe_alignment(run.alignment)}"
        lines.append(line)
    return lines


def frame_line(store: Path) -> str:
    """The frame ``map.yaml`` and goals are in, for the robot stack (``care frame`` says how
    to publish it where the recording's TF tree lacks it)."""
    from care_maps.query.goals import GoalMaker

    plan = GoalMaker.plan(store)
    publish = f", publish it with `care frame {store}`" if plan.publish else ""
    return f"{Path(store) / 'map.yaml'}: in frame {plan.frame_id!r}{publish}"


def store_lines(store: Path) -> list[str]:
    """:func:`ingest_line`, the map frame, and each map's candidates (the maps present)."""
    from care_maps.core.store import Store, read_table

    opened = Store(store)
    lines = [ingest_line(store)]
    geometry = geometry_line(store)
    if geometry is not None:
        lines.append(geometry)
    lines += runs_lines(store)
    lines.append(f"{store}: {opened.map_frame.describe()}")
    for table, what in (("cells", "grid cells"), ("instances", "instances")):
        path = opened.table_path(table)
        if path.is_file():
            views = read_table(path, ["num_views"]).column("num_views").to_numpy()
            lines.append(
                f"{path}: {len(views)} {what}, {int((views >= 2).sum())} seen from 2+ views"
            )
    if opened.table_path("cells").is_file():
        lines.append(frame_line(store))
    return lines
