"""``care run``: recording(s) in, maps, the success table and Rerun files out, in one call.

Chains ingest (:func:`ingest.pipeline.run_ingest`), both maps (:func:`fuse.grid.build_grid`,
:func:`fuse.instances.build_instances`) and the evaluation (:func:`evaluate.job.run_eval`).
Every stage skips work that is already done, so re-running is cheap. With no recording it
runs on the bundled sample (``data/sample``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow.parquet as pq

from care.errors import EvalError
from evaluate.groundtruth import GtSource
from evaluate.job import EvalConfig, Scene, run_eval, with_ground_truth
from evaluate.report import Report
from evaluate.viz import write_evaluation_rrd
from fuse.grid import GridConfig, build_grid
from fuse.instances import InstanceConfig, build_instances
from ingest.pipeline import IngestConfig, run_ingest
from query.map import load_map
from world.dataset_index import INDEX_NAME, read_index

__all__ = ["SAMPLE", "RunConfig", "RunResult", "recordings_of", "run_all"]

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "sample"
"""The bundled sample dataset (one sample-world recording with ground truth)."""


@dataclass(frozen=True)
class RunConfig:
    """The main job's settings (the CLI's ``care run`` options)."""

    encoder: str = "labels"
    """Encoder of ``care ingest`` (``labels``: the sample world's perception model)."""
    grid: GridConfig = field(default_factory=lambda: GridConfig(stride=2))
    """Grid map settings (every second depth pixel: the same map at a quarter of the work)."""
    instances: InstanceConfig = field(default_factory=InstanceConfig)
    """Instance map settings."""
    evaluation: EvalConfig = field(default_factory=EvalConfig)
    """What the evaluation runs."""
    workers: int | None = None
    """Local processes of the evaluation (default: one per CPU)."""
    ray_address: str | bool | None = None
    """Evaluate scenes as Ray tasks: True for a local Ray, an address for a cluster."""
    progress: bool = True
    """Show progress bars."""
    gt: tuple[Path, ...] = ()
    """Ground truth of each recording, in order (default: its index entry's, or beside it)."""
    gt_defaults: GtSource = field(default_factory=GtSource)
    """Format, frame transform and class map of ground truth that names none."""


@dataclass(frozen=True)
class RunResult:
    """What :func:`run_all` made."""

    report: Report
    stores: tuple[Path, ...]
    rrds: tuple[Path, ...]

    def rerun_command(self) -> str:
        return "rerun " + " ".join(str(p) for p in self.rrds)


def recordings_of(source: Path) -> list[tuple[str, Path]]:
    """``(name, recording)`` pairs of a dataset directory (``index.json``) or one recording."""
    source = Path(source)
    if source.is_dir() and (source / INDEX_NAME).is_file():
        return [(entry.name, entry.recording) for entry in read_index(source)]
    if not source.exists():
        msg = f"{source}: no such recording or dataset directory"
        raise EvalError(msg)
    return [(source.stem if source.suffix else source.name, source)]


def gt_sources_of(source: Path) -> list[GtSource]:
    """The ground truth each recording of ``source`` names in its index entry (if any)."""
    source = Path(source)
    if source.is_dir() and (source / INDEX_NAME).is_file():
        return [
            GtSource.of(e.gt, e.gt_format, e.gt_transform, e.gt_class_map)
            for e in read_index(source)
        ]
    return [GtSource()]


def _scenes_with_gt(
    recordings: Sequence[tuple[str, Path]],
    sources: Sequence[GtSource],
    config: RunConfig,
    out: Path,
) -> list[Scene]:
    """Each recording's scene with its ground truth resolved before any work is done: a
    recording without ground truth stops the run at once."""
    scenes = [
        Scene(name, out / "stores" / name, Path(rec).resolve(), gt=src)
        for (name, rec), src in zip(recordings, sources, strict=True)
    ]
    scenes = with_ground_truth(scenes, config.gt, config.gt_defaults)
    for scene in scenes:
        scene.gt.load(scene.recording)  # a corrupt file stops the run before the ingest
    return scenes


def run_all(source: Path | None, out: Path, config: RunConfig | None = None) -> RunResult:
    """Ingest, fuse and evaluate every recording of ``source`` (default the bundled sample)
    into ``out``: ``out/stores/<name>``, ``out/<name>.{grid,instances,eval}.rrd`` and the
    evaluation outputs (``results.md``, Parquet, plots) in ``out/eval``."""
    config = config or RunConfig()
    out = Path(out)
    recordings = recordings_of(source or SAMPLE)
    planned = _scenes_with_gt(recordings, gt_sources_of(source or SAMPLE), config, out)
    scenes, rrds = [], []
    for (name, recording), plan in zip(recordings, planned, strict=True):
        store = out / "stores" / name
        run_ingest(
            IngestConfig(
                recording=recording, out=store, encoder=config.encoder, progress=config.progress
            )
        )
        grid_rrd, inst_rrd = out / f"{name}.grid.rrd", out / f"{name}.instances.rrd"
        fresh = not (store / "cells.parquet").is_file() or not grid_rrd.is_file()
        build_grid(store, config.grid, rrd=grid_rrd if fresh else None)
        fresh = not (store / "instances.parquet").is_file() or not inst_rrd.is_file()
        build_instances(store, config.instances, rrd=inst_rrd if fresh else None)
        scenes.append(plan)
        rrds += [p for p in (grid_rrd, inst_rrd) if p.is_file()]
    eval_dir = out / "eval"
    report = run_eval(
        scenes, config.evaluation, eval_dir,
        workers=config.workers, ray_address=config.ray_address, progress=config.progress,
    )  # fmt: skip
    attempts = pq.read_table(eval_dir / "attempts.parquet")
    for scene in scenes:
        maps = {kind: load_map(scene.store, kind) for kind in config.evaluation.maps}  # type: ignore[misc]
        path = out / f"{scene.name}.eval.rrd"
        write_evaluation_rrd(path, attempts, report.summary, maps, scene=scene.name)
        rrds.append(path)
    return RunResult(report, tuple(s.store for s in scenes), tuple(rrds))
