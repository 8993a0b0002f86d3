"""Sample-world recordings and datasets: generate, render, write with the real writers.

A *dataset* is a directory of recordings (``scene_000.mcap``, or ``scene_000/`` rosbag2
directories, or ``scene_000.bag``), each with its ground truth beside it
(``scene_000.gt.parquet`` + ``scene_000.gt.json``), and an ``index.json`` listing them.
Scenes are independent, so they are made in a process pool; a scene whose recording and
ground truth already exist with the same settings is skipped, so re-running resumes.

A dataset is whole or absent: it is made in a staged copy beside ``--out`` (the scenes of
the previous version hard-linked in, so those up to date are kept) and swapped in as one
unit (:func:`care_maps.core.outputs.whole_output`), so a full disk, Ctrl-C or a kill leaves the
previous dataset, or none, never a recording without its ground truth or ``index.json``.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from care_maps.core.errors import WorldError
from care_maps.core.frames import Frame
from care_maps.core.outputs import (
    OutputKind,
    atomic_write_text,
    check_file_output,
    is_ours,
    whole_output,
    write_marker,
)
from care_maps.ingest.formats import RecordingFormat
from care_maps.runtime.parallel import Runner, run_tasks
from care_maps.truth.dataset_index import INDEX_NAME
from care_maps.truth.formats.native import gt_paths, write_native
from care_maps.truth.model import GroundTruth
from care_maps.world.presets import PRESETS, WorldPreset, WorldSettings
from care_maps.world.render import RenderConfig, Renderer
from care_maps.world.scene import Scene, SceneConfig, generate_scene
from care_maps.world.trajectory import TrajectoryConfig, plan_trajectory

__all__ = [
    "FORMAT_SUFFIX",
    "DatasetConfig",
    "RecordingSummary",
    "dataset_statistics",
    "make_dataset",
    "make_recording",
    "recording_path",
    "scene_config_of",
    "scene_seed",
]

Format = RecordingFormat
FORMAT_SUFFIX: dict[str, str] = {fmt: fmt.suffix for fmt in RecordingFormat}
MIN_VISIBLE_PIXELS = 20
"""An object seen on fewer pixels than this over the whole recording counts as unseen."""


@dataclass(frozen=True)
class DatasetConfig:
    """One ``care sample make`` job; the CLI builds it from its flags."""

    out: Path
    """Directory of the dataset (created)."""
    scenes: int = 1
    """Number of scenes."""
    seed: int = 0
    """Dataset seed; scene i gets a seed of its own drawn from (seed, i) (:func:`scene_seed`)."""
    fmt: Format = RecordingFormat.MCAP
    """Container format of the recordings."""
    width: int = RenderConfig.width
    """Image width."""
    height: int = RenderConfig.height
    """Image height."""
    frames: int | None = None
    """Frames per recording; default 25 per room."""
    num_rooms: int | None = None
    """Rooms per scene (1 to 6); default drawn per scene from 2 to 5."""
    compressed_rgb: bool = False
    """JPEG colour (CompressedImage) instead of raw rgb8."""
    preset: WorldPreset = WorldPreset.DEFAULT
    """The preset ``world`` started from (recorded in ``index.json``)."""
    world: WorldSettings = field(default_factory=lambda: PRESETS[WorldPreset.DEFAULT])
    """Every scene and perception knob (:mod:`care_maps.world.presets`)."""
    workers: int = 2
    """Processes making scenes in parallel."""
    rrd: Path | None = None
    """Write a Rerun recording of the scenes (meshes, ground-truth boxes, trajectories)."""
    progress: bool = True
    """Show a tqdm progress bar."""


@dataclass(frozen=True)
class RecordingSummary:
    """What :func:`make_recording` made; one entry of ``index.json``."""

    name: str
    recording: str
    """Path relative to the dataset directory."""
    seed: int
    rooms: list[str]
    num_frames: int
    num_instances: int
    instances_per_room: list[int]
    """Instances of each room, in room order."""
    classes: list[str]
    """Classes present, sorted."""
    unseen_instances: list[int]
    """Instances seen on fewer than MIN_VISIBLE_PIXELS pixels in the whole recording."""
    skipped: bool = False
    """True when an up-to-date recording was already there."""


def scene_seed(seed: int, index: int) -> int:
    """Seed of scene ``index`` of a dataset made with ``seed`` (independent streams)."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def recording_path(out: Path, index: int, fmt: Format) -> Path:
    """Where scene ``index`` of a dataset in ``out`` is written."""
    return Path(out) / f"scene_{index:03d}{FORMAT_SUFFIX[fmt]}"


def _settings(config: DatasetConfig, seed: int) -> dict[str, Any]:
    """What determines a recording's bytes; stored in its ground truth to decide skipping.

    The world knobs join only where they differ from the default world, so a default
    dataset's settings name no world knob at all."""
    world = config.world
    extra = {} if world == WorldSettings() else {"world": world.as_json()}
    return {
        "seed": seed,
        "fmt": config.fmt,
        "width": config.width,
        "height": config.height,
        "frames": config.frames,
        "num_rooms": config.num_rooms,
        "compressed_rgb": config.compressed_rgb,
        "clutter": world.clutter,
        "point_density_objects": world.point_density_objects,
        "point_density_structure": world.point_density_structure,
        **extra,
    }


class _VisibilityCounter:
    """Passes frames through while counting each instance's pixels."""

    def __init__(self, frames: Iterable[Frame], bar: tqdm | None) -> None:
        self.frames = frames
        self.pixels: dict[int, int] = {}
        self.count = 0
        self.bar = bar

    def __iter__(self) -> Iterator[Frame]:
        for frame in self.frames:
            counts = np.bincount(frame.extras["instance"].ravel())
            for i in np.flatnonzero(counts):
                self.pixels[int(i)] = self.pixels.get(int(i), 0) + int(counts[i])
            self.count += 1
            if self.bar is not None:
                self.bar.update(1)
            yield frame


def make_recording(
    path: Path,
    scene_config: SceneConfig,
    render_config: RenderConfig | None = None,
    *,
    frames: int | None = None,
    fmt: Format = RecordingFormat.MCAP,
    compressed_rgb: bool = False,
    trajectory: TrajectoryConfig | None = None,
    progress: bool = False,
    settings: dict[str, Any] | None = None,
    perception: dict[str, Any] | None = None,
) -> tuple[Scene, GroundTruth, RecordingSummary]:
    """Generate the scene, render its exploration into a recording at ``path`` and save its
    ground truth beside it (with ``perception``, the perception model the ``labels``
    encoder is to use, where given). Returns the scene, the ground truth and a summary."""
    from care_maps.ingest.write import write_recording

    path = Path(path)
    scene = generate_scene(scene_config)
    poses = plan_trajectory(scene, frames, trajectory)
    renderer = Renderer(scene, render_config)
    bar = tqdm(total=len(poses), desc=f"render {path.name}", unit="frame", disable=not progress)
    counter = _VisibilityCounter(renderer.render_all(poses), bar)
    try:
        write_recording(
            path,
            counter,
            fmt=fmt,
            compressed_rgb=compressed_rgb,
            label_names=scene.class_names,
        )
    finally:
        bar.close()
    unseen = [
        o.instance_id
        for o in scene.objects
        if counter.pixels.get(o.instance_id, 0) < MIN_VISIBLE_PIXELS
    ]
    gt = scene.ground_truth(
        {
            "settings": settings or {"seed": scene_config.seed},
            "num_frames": counter.count,
            "unseen_instances": unseen,
            "visible_pixels": {str(k): v for k, v in sorted(counter.pixels.items()) if k > 0},
            **({"perception": perception} if perception else {}),
        }
    )
    write_native(gt, path)
    summary = RecordingSummary(
        name=path.name.removesuffix(FORMAT_SUFFIX[fmt]) if FORMAT_SUFFIX[fmt] else path.name,
        recording=path.name,
        seed=scene_config.seed,
        rooms=[r.name for r in scene.rooms],
        num_frames=counter.count,
        num_instances=len(scene.objects),
        instances_per_room=[
            sum(o.room_id == r.room_id for o in scene.objects) for r in scene.rooms
        ],
        classes=sorted({o.class_name for o in scene.objects}),
        unseen_instances=unseen,
    )
    return scene, gt, summary


def _up_to_date(path: Path, settings: dict[str, Any]) -> RecordingSummary | None:
    pq_path, json_path = gt_paths(path)
    if not (path.exists() and pq_path.is_file() and json_path.is_file()):
        return None
    try:
        doc = json.loads(json_path.read_text())
    except json.JSONDecodeError:
        return None
    info = doc.get("info", {})
    if info.get("settings") != settings:
        return None
    return RecordingSummary(
        name=path.name.removesuffix(path.suffix) if path.suffix else path.name,
        recording=path.name,
        seed=settings["seed"],
        rooms=[r["name"] for r in doc["rooms"]],
        num_frames=int(info.get("num_frames", 0)),
        num_instances=len(doc["instances"]),
        instances_per_room=[
            sum(r["room_id"] == room["room_id"] for r in doc["instances"]) for room in doc["rooms"]
        ],
        classes=sorted({r["class_name"] for r in doc["instances"]}),
        unseen_instances=list(info.get("unseen_instances", [])),
        skipped=True,
    )


def _make_one(config: DatasetConfig, index: int, progress: bool) -> RecordingSummary:
    """Worker: one scene of a dataset (skipped when up to date)."""
    seed = scene_seed(config.seed, index)
    path = recording_path(config.out, index, config.fmt)
    settings = _settings(config, seed)
    done = _up_to_date(path, settings)
    if done is not None:
        return done
    scene_config = scene_config_of(config, index)
    threads = 1 if config.workers > 1 else 0
    render = RenderConfig(width=config.width, height=config.height, threads=threads)
    *_, summary = make_recording(
        path,
        scene_config,
        render,
        frames=config.frames,
        fmt=config.fmt,
        compressed_rgb=config.compressed_rgb,
        progress=progress,
        settings=settings,
        perception=settings.get("world", {}).get("perception"),
    )
    return summary


def make_dataset(config: DatasetConfig, *, finish: Callable[[Path], object] | None = None) -> Path:
    """Make (or complete) the dataset of ``config``; returns the path of its ``index.json``.

    ``finish(index)``: more work on the dataset (ground truth in other formats, measured
    statistics written into the index), run on the staged dataset before it is swapped in,
    so that it is part of the one unit that appears whole or not at all."""
    _check(config)
    out = Path(config.out)
    if config.rrd is not None:  # before rendering: a file that is not ours is never replaced
        check_file_output(config.rrd)
    _adopt(out)
    with whole_output(out, OutputKind.DATASET) as staged:
        index = _write_dataset(dataclasses.replace(config, out=staged))
        if finish is not None:
            finish(index)
    if config.rrd is not None:
        from care_maps.world.viz import log_dataset

        scenes = [scene_config_of(config, i) for i in range(config.scenes)]
        log_dataset(
            config.rrd,
            scenes,
            config.frames,
            RenderConfig(width=config.width, height=config.height),
        )
    return out / INDEX_NAME


def _check(config: DatasetConfig) -> None:
    """Refuse, before anything is written, settings that cannot make a dataset."""
    if config.scenes < 1:
        msg = f"--scenes {config.scenes}: make at least one scene"
        raise WorldError(msg)
    if config.width < 16 or config.height < 16:
        msg = f"--width/--height {config.width}x{config.height}: images must be at least 16x16"
        raise WorldError(msg)
    if config.frames is not None and config.frames < 1:
        msg = f"--frames {config.frames}: record at least one frame (leave it out for 25 per room)"
        raise WorldError(msg)
    if config.num_rooms is not None and not 1 <= config.num_rooms <= 6:
        msg = f"--rooms {config.num_rooms}: the sample world makes 1 to 6 rooms"
        raise WorldError(msg)


def _adopt(out: Path) -> None:
    """Mark a dataset of ours that lacks the marker (the bundled sample is committed without
    it; it is known by its index), so that it may be completed; a directory of the user's
    is left alone (and refused by :func:`care_maps.core.outputs.check_output`)."""
    index = out / INDEX_NAME
    if out.is_symlink() or is_ours(out) or not index.is_file():
        return
    if b"care_sample_dataset" in index.read_bytes():
        write_marker(out, OutputKind.DATASET)


def _write_dataset(config: DatasetConfig) -> Path:
    """Make every scene of ``config`` in ``config.out`` (a staged directory) and write its
    ``index.json``; returns the index's path."""
    out = Path(config.out)
    summaries: dict[int, RecordingSummary] = {}
    workers = max(1, min(config.workers, config.scenes))
    bar = tqdm(total=config.scenes, desc="sample scenes", unit="scene", disable=not config.progress)
    try:
        if workers == 1:
            for i in range(config.scenes):
                summaries[i] = _make_one(config, i, config.progress)
                bar.update(1)
        else:  # runtime's pool: its workers answer SIGTERM and SIGHUP and stop with the run
            make = functools.partial(_make_one, config, progress=False)
            for i, summary in run_tasks(make, range(config.scenes), Runner(workers=workers)):
                summaries[i] = summary
                bar.update(1)
    finally:
        bar.close()
    config_doc = {
        k: v
        for k, v in asdict(config).items()
        if k not in ("out", "rrd", "workers", "progress", "world", "preset")
    }
    world = config.world
    config_doc.update(
        clutter=world.clutter,
        point_density_objects=world.point_density_objects,
        point_density_structure=world.point_density_structure,
        preset=str(config.preset),
        world=world.as_json(),
    )
    recordings = [asdict(summaries[i]) for i in range(config.scenes)]
    index = {
        "care_sample_dataset": 1,
        "config": config_doc,
        "statistics": dataset_statistics(recordings),
        "recordings": recordings,
    }
    index_path = out / INDEX_NAME
    atomic_write_text(index_path, json.dumps(index, indent=1))
    return index_path


def scene_config_of(config: DatasetConfig, index: int) -> SceneConfig:
    """The scene config of scene ``index`` of a dataset."""
    return SceneConfig(
        seed=scene_seed(config.seed, index),
        num_rooms=config.num_rooms,
        **config.world.scene_values(),
    )


def dataset_statistics(recordings: list[dict[str, Any]]) -> dict[str, Any]:
    """What a dataset holds: scenes, rooms, instances (per room: mean, min, max) and classes
    (present in some scene; per scene on average)."""
    per_room = [n for r in recordings for n in r.get("instances_per_room", [])]
    classes = sorted({c for r in recordings for c in r["classes"]})
    return {
        "scenes": len(recordings),
        "rooms": len(per_room),
        "instances": int(sum(r["num_instances"] for r in recordings)),
        "instances_per_room": {
            "mean": round(float(np.mean(per_room)), 2) if per_room else 0.0,
            "min": int(min(per_room, default=0)),
            "max": int(max(per_room, default=0)),
        },
        "classes": len(classes),
        "classes_per_scene": round(float(np.mean([len(r["classes"]) for r in recordings])), 2),
    }
