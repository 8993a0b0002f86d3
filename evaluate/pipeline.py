"""``care run``: recording(s) in, maps, the success table and Rerun files out, in one call.

Chains ingest (:func:`ingest.pipeline.run_ingest`), both maps (:func:`fuse.grid.build_grid`,
:func:`fuse.instances.build_instances`) and the evaluation (:func:`evaluate.job.run_eval`).
Every stage skips work that is already done, so re-running is cheap. With no recording it
runs on the bundled sample (``data/sample``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pyarrow.compute as pc
import pyarrow.parquet as pq

from care.errors import EvalError
from evaluate.job import EvalConfig, Scene, run_eval
from evaluate.report import Report
from evaluate.viz import write_evaluation_rrd
from fuse.grid import GridConfig, build_grid
from fuse.instances import InstanceConfig, build_instances
from fuse.viz_grid import log_grid
from ingest.pipeline import IngestConfig, run_ingest
from query.map import load_map
from world.dataset_index import INDEX_NAME, read_index
from world.groundtruth import GroundTruth, gt_paths

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
    rrd_ingest: bool = True
    """Also write ``<name>.ingest.rrd`` (camera images, depth, the map building up)."""
    rrd_class: str | None = None
    """Class of the grid recording's confidence layer (default: one layer per query class of
    the scene's evaluation)."""


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


def run_all(source: Path | None, out: Path, config: RunConfig | None = None) -> RunResult:
    """Ingest, fuse and evaluate every recording of ``source`` (default the bundled sample)
    into ``out``: ``out/stores/<name>``, ``out/<name>.{ingest,grid,instances,eval}.rrd`` (one
    Rerun recording id per scene, so they open together) and the evaluation outputs
    (``results.md``, Parquet, plots) in ``out/eval``."""
    config = config or RunConfig()
    out = Path(out)
    recordings = recordings_of(source or SAMPLE)
    missing = [str(rec) for _, rec in recordings if not gt_paths(rec)[1].is_file()]
    if missing:
        msg = (
            f"{missing[0]}: no ground truth beside it ({gt_paths(Path(missing[0]))[1].name}); "
            "`care run` evaluates sample-world recordings; use `care ingest`, `care fuse` and "
            "`care query` for others"
        )
        raise EvalError(msg)
    scenes, grid_due = [], {}
    for name, recording in recordings:
        store = out / "stores" / name
        ingest_rrd = out / f"{name}.ingest.rrd" if config.rrd_ingest else None
        run_ingest(
            IngestConfig(
                recording=recording, out=store, encoder=config.encoder, progress=config.progress,
                rrd=ingest_rrd,
            )
        )  # fmt: skip
        grid_rrd, inst_rrd = out / f"{name}.grid.rrd", out / f"{name}.instances.rrd"
        fresh = not (store / "cells.parquet").is_file() or not grid_rrd.is_file()
        build_grid(store, config.grid)
        grid_due[name] = fresh or config.rrd_class is not None  # logged after the evaluation
        fresh = not (store / "instances.parquet").is_file() or not inst_rrd.is_file()
        build_instances(store, config.instances, rrd=inst_rrd if fresh else None)
        scenes.append(Scene(name, store, Path(recording).resolve()))
    eval_dir = out / "eval"
    report = run_eval(
        [s.store for s in scenes], config.evaluation, eval_dir,
        workers=config.workers, ray_address=config.ray_address, progress=config.progress,
    )  # fmt: skip
    attempts = pq.read_table(eval_dir / "attempts.parquet")
    rrds: list[Path] = []
    for scene in scenes:
        if grid_due[scene.name]:  # the confidence of the scene's query classes (or --rrd-class)
            mine = attempts.filter(pc.equal(attempts.column("scene"), scene.name))
            classes = list(dict.fromkeys(mine.column("target").to_pylist()))
            target = config.rrd_class if config.rrd_class is not None else classes or None
            log_grid(scene.store, out / f"{scene.name}.grid.rrd", target=target, scene=scene.name)
        maps = {kind: load_map(scene.store, kind) for kind in config.evaluation.maps}  # type: ignore[misc]
        path = out / f"{scene.name}.eval.rrd"
        write_evaluation_rrd(
            path, attempts, report.summary, maps, scene=scene.name,
            gt=GroundTruth.load(scene.recording), store=scene.store,
        )  # fmt: skip
        stages = ("ingest", "grid", "instances", "eval")
        rrds += [p for p in (out / f"{scene.name}.{s}.rrd" for s in stages) if p.is_file()]
    return RunResult(report, tuple(s.store for s in scenes), tuple(rrds))
