"""``care run``: recording(s) in, maps, the success table and Rerun files out, in one call.

Chains ingest (:func:`ingest.pipeline.run_ingest`), both maps (:func:`fuse.grid.build_grid`,
:func:`fuse.instances.build_instances`) and the evaluation (:func:`evaluate.job.run_eval`).
Every stage skips work that is already done, so re-running is cheap. With no recording it
runs on the bundled sample (``data/sample``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pyarrow.compute as pc
import pyarrow.parquet as pq

from care.errors import EvalError
from care.outputs import owned_output
from evaluate.config import RunConfig
from evaluate.groundtruth import GtSource
from evaluate.job import Scene, run_eval, with_ground_truth
from evaluate.report import Report
from evaluate.viz import write_evaluation_rrd
from fuse.grid import build_grid
from fuse.instances import build_instances
from fuse.viz_grid import log_grid
from ingest.pipeline import IngestConfig, run_ingest
from ingest.readers import is_recording, recordings_in
from query.map import load_map
from world.dataset_index import INDEX_NAME, read_index

__all__ = ["SAMPLE", "RunConfig", "RunResult", "recordings_of", "run_all"]

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "sample"
"""The bundled sample dataset (one sample-world recording with ground truth)."""


@dataclass(frozen=True)
class RunResult:
    """What :func:`run_all` made."""

    report: Report | None
    """The evaluation's report; None when no recording had ground truth."""
    stores: tuple[Path, ...]
    rrds: tuple[Path, ...]
    unevaluated: tuple[str, ...] = ()
    """Recordings mapped but not evaluated: no ground truth named or beside them."""

    def rerun_command(self) -> str:
        return "rerun " + " ".join(str(p) for p in self.rrds)


def recordings_of(source: Path) -> list[tuple[str, Path]]:
    """``(name, recording)`` pairs of a dataset directory (``index.json``), one recording, or
    a plain folder of recordings (any mix of MCAP, rosbag2 and ROS 1; named by file stem)."""
    source = Path(source)
    if source.is_dir() and (source / INDEX_NAME).is_file():
        return [(entry.name, entry.recording) for entry in read_index(source)]
    if not source.exists():
        msg = f"{source}: no such recording or dataset directory"
        raise EvalError(msg)
    if is_recording(source):
        return [(source.stem if source.suffix else source.name, source)]
    if source.is_dir():
        found = recordings_in(source)
        if not found:
            msg = (
                f"{source}: no recordings in it (.mcap, .bag or rosbag2 folders) and no "
                f"{INDEX_NAME}; pass a recording, a folder of them, or a dataset"
            )
            raise EvalError(msg)
        names = [p.stem if p.is_file() else p.name for p in found]
        twins = sorted({n for n in names if names.count(n) > 1})
        if twins:
            msg = f"{source}: recordings {', '.join(twins)} share a name; rename one"
            raise EvalError(msg)
        return list(zip(names, found, strict=True))
    return [(source.stem, source)]  # not a known format: ingest says which


def gt_sources_of(source: Path) -> list[GtSource]:
    """The ground truth each recording of ``source`` names in its index entry (if any)."""
    source = Path(source)
    if source.is_dir() and (source / INDEX_NAME).is_file():
        return [
            GtSource.of(e.gt, e.gt_format, e.gt_transform, e.gt_class_map)
            for e in read_index(source)
        ]
    return [GtSource() for _ in recordings_of(source)]


def _scenes_with_gt(
    recordings: Sequence[tuple[str, Path]],
    sources: Sequence[GtSource],
    config: RunConfig,
    out: Path,
) -> list[tuple[Scene, bool]]:
    """Each recording's scene and whether it has ground truth, resolved before any work is
    done: ground truth that is named (``--gt``, ``index.json``) must load, else the run
    stops at once; a recording with none named or beside it is mapped but not evaluated."""
    scenes = [
        Scene(name, out / "stores" / name, Path(rec).resolve(), gt=src)
        for (name, rec), src in zip(recordings, sources, strict=True)
    ]
    scenes = with_ground_truth(scenes, config.gt, config.gt_defaults)
    out_scenes = []
    for scene in scenes:
        has = scene.gt.path is not None or scene.gt.available(scene.recording)
        if has:
            scene.gt.load(scene.recording)  # a corrupt file stops the run before the ingest
        out_scenes.append((scene, has))
    return out_scenes


def run_all(source: Path | None, out: Path, config: RunConfig | None = None) -> RunResult:
    """Ingest, fuse and evaluate every recording of ``source`` (default the bundled sample)
    into ``out``: ``out/stores/<name>``, ``out/<name>.{ingest,grid,instances,eval}.rrd`` (one
    Rerun recording id per scene, so they open together) and the evaluation outputs
    (``results.md``, Parquet, plots) in ``out/eval``. Recordings without ground truth get
    their maps and Rerun files and are listed in ``unevaluated``."""
    config = config or RunConfig()
    out = Path(out)
    recordings = recordings_of(source or SAMPLE)
    planned = _scenes_with_gt(recordings, gt_sources_of(source or SAMPLE), config, out)
    with owned_output(out, "run", [rec for _, rec in recordings]):
        scenes, unevaluated, grid_due = [], [], {}
        for (name, recording), (plan, has_gt) in zip(recordings, planned, strict=True):
            store = out / "stores" / name
            ingest_rrd = out / f"{name}.ingest.rrd" if config.rrd_ingest else None
            run_ingest(
                IngestConfig(
                    recording=recording, out=store, encoder=config.encoder,
                    encoder_options=config.encoder_options, vocabulary=config.vocabulary,
                    progress=config.progress, rrd=ingest_rrd,
                )
            )  # fmt: skip
            grid_rrd, inst_rrd = out / f"{name}.grid.rrd", out / f"{name}.instances.rrd"
            fresh = not (store / "cells.parquet").is_file() or not grid_rrd.is_file()
            build_grid(store, config.grid)
            grid_due[name] = fresh or config.rrd_class is not None  # logged after the evaluation
            fresh = not (store / "instances.parquet").is_file() or not inst_rrd.is_file()
            build_instances(store, config.instances, rrd=inst_rrd if fresh else None)
            if has_gt:
                scenes.append(plan)
            else:
                unevaluated.append(name)
        report, attempts = None, None
        if scenes:
            report = run_eval(
                scenes, config.evaluation, out / "eval",
                workers=config.workers, ray_address=config.ray_address, progress=config.progress,
            )  # fmt: skip
            attempts = pq.read_table(out / "eval" / "attempts.parquet")
        evaluated = {scene.name: scene for scene in scenes}
        rrds: list[Path] = []
        for name, _ in recordings:
            store = out / "stores" / name
            if grid_due[name]:  # the confidence of the scene's query classes (or --rrd-class)
                target = config.rrd_class
                if target is None and name in evaluated:
                    mine = attempts.filter(pc.equal(attempts.column("scene"), name))
                    target = list(dict.fromkeys(mine.column("target").to_pylist())) or None
                log_grid(store, out / f"{name}.grid.rrd", target=target, scene=name)
            if name in evaluated:
                scene = evaluated[name]
                maps = {kind: load_map(store, kind) for kind in config.evaluation.maps}  # type: ignore[misc]
                write_evaluation_rrd(
                    out / f"{name}.eval.rrd", attempts, report.summary, maps, scene=name,
                    gt=scene.gt.load(scene.recording), store=store,
                )  # fmt: skip
            stages = ("ingest", "grid", "instances", "eval")
            rrds += [p for p in (out / f"{name}.{s}.rrd" for s in stages) if p.is_file()]
        stores = tuple(out / "stores" / name for name, _ in recordings)
        return RunResult(report, stores, tuple(rrds), tuple(unevaluated))
