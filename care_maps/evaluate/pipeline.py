"""``care run``: recording(s) in, maps, the success table and Rerun files out, in one call.

Chains the stage functions: :func:`ingest.ingest`, :func:`fuse.fuse_grid` and
:func:`fuse.fuse_instances` for each recording (one task a recording, run serially, in a
local process pool or on Ray: :mod:`care_maps.runtime.parallel`), then :func:`evaluate.evaluate`. Every
stage skips work that is already done, so re-running is cheap and an interrupted run
resumes. With no recording it runs on the bundled sample (``care_maps/data/sample``).

The stages a task runs (ingest, fusion, the Rerun logging) are imported by the task, not by
this module: the driver of a process pool or of Ray never fuses, and importing torch, numba
and Rerun there cost it about 3.5 s on one core before the workers got their first task.

What the job makes is its :class:`RunConfig`; how it runs (workers, Ray, the tasks'
resources, progress bars) is one :class:`care_maps.runtime.execution.Execution`, handed to every stage.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import overload

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from tqdm import tqdm

from care_maps.core.errors import CareError, EvalError
from care_maps.core.outputs import OutputKind, owned_output
from care_maps.evaluate.api import evaluate
from care_maps.evaluate.config import RunConfig
from care_maps.evaluate.groundtruth import GtSource
from care_maps.evaluate.job import Scene, with_ground_truth
from care_maps.evaluate.report import Report
from care_maps.ingest.readers import is_recording, recordings_in
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution
from care_maps.runtime.parallel import Runner, open_runner, run_tasks
from care_maps.truth.dataset_index import INDEX_NAME, read_index

__all__ = [
    "SAMPLE",
    "RecordingOutcome",
    "RecordingTask",
    "RunConfig",
    "RunResult",
    "SceneLogTask",
    "map_recordings",
    "one_thread_each",
    "recordings_of",
    "run_all",
]

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
    failed: tuple[tuple[str, str], ...] = ()
    """``(name, one-line error)`` of every recording whose ingest or maps failed."""

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


@dataclass(frozen=True)
class RecordingTask:
    """One recording's ingest and both maps: a task of :func:`care_maps.runtime.parallel.run_tasks`,
    with everything it needs in its fields (no global state), so it runs the same in this
    process, a pool worker or a Ray worker on another node."""

    name: str
    recording: Path
    out: Path
    """The run's output folder: the store goes to ``out/stores/<name>``."""
    config: RunConfig
    run: Execution = DEFAULT_EXECUTION
    """How the task's stages run (:func:`run_all` turns their progress bars off where tasks
    run side by side, and their read-ahead: :func:`one_thread_each`)."""

    @property
    def store(self) -> Path:
        return self.out / "stores" / self.name

    def __call__(self) -> RecordingOutcome:
        try:
            return self._run()
        except Exception as err:
            first = str(err).splitlines()[0] if str(err) else ""
            why = first if isinstance(err, CareError) else f"{type(err).__name__}: {first}"
            return RecordingOutcome(self.name, error=why)

    def _run(self) -> RecordingOutcome:
        from care_maps.fuse.api import fuse_grid, fuse_instances
        from care_maps.fuse.viz_instances import log_instances
        from care_maps.ingest.api import ingest
        from care_maps.ingest.pipeline import IngestConfig

        config, out, name, run = self.config, self.out, self.name, self.run
        ingest_rrd = out / f"{name}.ingest.rrd" if config.rrd_ingest else None
        store = ingest(
            self.recording,
            self.store,
            IngestConfig(
                encoder=config.encoder, encoder_options=config.encoder_options,
                vocabulary=config.vocabulary, rrd=ingest_rrd, read=config.read,
                select=config.select,
            ),
            run=run,
        )  # fmt: skip
        grid_rrd, inst_rrd = out / f"{name}.grid.rrd", out / f"{name}.instances.rrd"
        grid_fresh = not (store.path / "cells.parquet").is_file() or not grid_rrd.is_file()
        fuse_grid(store, config.grid, run=run)
        fresh = not (store.path / "instances.parquet").is_file() or not inst_rrd.is_file()
        fuse_instances(store, config.instances, run=run)
        if fresh:
            log_instances(store.path, inst_rrd)
        return RecordingOutcome(name, grid_due=grid_fresh)


@dataclass(frozen=True)
class RecordingOutcome:
    """What a :class:`RecordingTask` left: its grid still to log, or its one-line error."""

    name: str
    grid_due: bool = False
    """The grid map is new (or has no Rerun file yet): log it after the evaluation."""
    error: str | None = None


@dataclass(frozen=True)
class SceneLogTask:
    """One recording's Rerun files after the evaluation: its grid map (when new) and its
    evaluation. A task of :func:`care_maps.runtime.parallel.run_tasks` like the recording's maps, so the
    scenes are logged in parallel too (done one after another in the driver, the logging
    was the serial tail that kept a pool of two near x1.1)."""

    name: str
    store: Path
    grid_rrd: Path | None
    """Log the grid here (None: it is current)."""
    target: tuple[str, ...] | None
    """The grid's confidence layers (None: the map's default class)."""
    eval_rrd: Path | None = None
    """Log the evaluation here (None: the recording was not evaluated)."""
    scene: Scene | None = None
    attempts: pa.Table | None = None
    """The scene's own attempts."""
    summary: pa.Table | None = None
    maps: tuple[str, ...] = ()

    @property
    def due(self) -> bool:
        return self.grid_rrd is not None or self.eval_rrd is not None

    def __call__(self) -> None:
        from care_maps.evaluate.viz import write_evaluation_rrd
        from care_maps.fuse.viz_grid import log_grid
        from care_maps.query.map import load_map

        if self.grid_rrd is not None:
            target = list(self.target) if self.target else None
            log_grid(self.store, self.grid_rrd, target=target, scene=self.name)
        if self.eval_rrd is not None and self.scene is not None:
            maps = {kind: load_map(self.store, kind) for kind in self.maps}
            write_evaluation_rrd(
                self.eval_rrd, self.attempts, self.summary, maps, scene=self.name,
                gt=self.scene.gt.load(self.scene.recording, self.store), store=self.store,
            )  # fmt: skip


def _log_task(
    name: str,
    out: Path,
    grid_due: bool,
    scene: Scene | None,
    attempts: pa.Table | None,
    report: Report | None,
    config: RunConfig,
) -> SceneLogTask:
    store = out / "stores" / name
    mine = None
    if attempts is not None and scene is not None:
        mine = attempts.filter(pc.equal(attempts.column("scene"), name))
    target = [config.rrd_class] if config.rrd_class is not None else None
    if target is None and mine is not None:  # the scene's query classes by default
        target = list(dict.fromkeys(mine.column("target").to_pylist())) or None
    grid_rrd = out / f"{name}.grid.rrd" if grid_due or config.rrd_class is not None else None
    if scene is None or report is None:
        return SceneLogTask(name, store, grid_rrd, tuple(target) if target else None)
    return SceneLogTask(
        name, store, grid_rrd, tuple(target) if target else None,
        eval_rrd=out / f"{name}.eval.rrd", scene=scene, attempts=mine,
        summary=report.summary, maps=tuple(config.evaluation.maps),
    )  # fmt: skip


@overload
def _run_task(task: RecordingTask) -> RecordingOutcome: ...
@overload
def _run_task(task: SceneLogTask) -> None: ...
def _run_task(task: RecordingTask | SceneLogTask) -> RecordingOutcome | None:
    return task()


def one_thread_each(run: Execution) -> Execution:
    """``run`` for recordings run side by side (a process pool, Ray): each task's maps
    fused in its one thread (``read_ahead=0``), not as a pipeline of three.

    The tasks are the parallelism there, each holding one of the CPUs it declares; a
    pipeline in every task oversubscribes them (8 recordings on 2 cores, `bench/dataset.py`:
    pool 84.9 -> 81.6 s, Ray 93.1 -> 87.8 s). ``read_ahead`` is how a build runs, not what
    it makes: the maps are the same bytes either way.
    """
    return replace(run, read_ahead=0)


def map_recordings(
    tasks: Sequence[RecordingTask], runner: Runner, *, progress: bool = True
) -> dict[str, RecordingOutcome]:
    """Run every recording's task on ``runner``; a failure is one line, the others go on.

    A dataset progress bar counts finished recordings; finished stores and maps are not
    redone (each stage's up-to-date check), so an interrupted run resumes.
    """
    outcomes: dict[str, RecordingOutcome] = {}
    with tqdm(total=len(tasks), desc="recordings", unit="rec", disable=not progress) as bar:
        for task, outcome in run_tasks(_run_task, tasks, runner):
            outcomes[task.name] = outcome
            if outcome.error is not None and len(tasks) > 1:  # a lone one is the run's error
                bar.write(f"error: {task.name}: {outcome.error}", file=sys.stderr)
            bar.set_postfix_str(task.name)
            bar.update(1)
    return outcomes


def run_all(
    source: Path | None,
    out: Path,
    config: RunConfig | None = None,
    *,
    run: Execution = DEFAULT_EXECUTION,
) -> RunResult:
    """Ingest, fuse and evaluate every recording of ``source`` (default the bundled sample)
    into ``out``: ``out/stores/<name>``, ``out/<name>.{ingest,grid,instances,eval}.rrd`` (one
    Rerun recording id per scene, so they open together) and the evaluation outputs
    (``results.md``, Parquet, plots) in ``out/eval``. Recordings without ground truth get
    their maps and Rerun files and are listed in ``unevaluated``.

    Each recording's ingest and maps are one task (:class:`RecordingTask`), run one after
    another, in a local process pool (``run.workers``) or on Ray (``run.backend``, at
    ``run.ray_address``, each task declaring ``run.task_cpus`` and ``run.task_memory``):
    :meth:`care_maps.runtime.parallel.Runner.of`; then the evaluation runs on the same pool. A recording that fails is reported in one line and left
    out (:attr:`RunResult.failed`); the others complete.

    What a kill at any instant leaves in ``out``: ``out/eval`` is the previous evaluation
    or the new one, whole (:func:`care_maps.core.outputs.whole_output`); each store's recording
    tables and ``meta.json`` are the previous ones or the new ones (staged, then swapped
    in); each map table is replaced by a rename, the map's main table last, so a map
    whose main table is the previous one is not current and the next run builds it
    again. The folder as a whole is not one unit, on purpose: the stores finished before
    the kill stay, and the next run resumes from them instead of starting over; it then
    brings every part to the new version. The ``.rrd`` files are streamed as they are
    logged (a kill can leave one cut short)."""
    config = config or RunConfig()
    out = Path(out)
    recordings = recordings_of(source or SAMPLE)
    planned = _scenes_with_gt(recordings, gt_sources_of(source or SAMPLE), config, out)
    runner = Runner.of(run)
    with owned_output(out, OutputKind.RUN, [rec for _, rec in recordings]):
        serial = not runner.uses_ray and (runner.workers <= 1 or len(recordings) <= 1)
        # stage progress bars in serial runs only: parallel ones show the dataset's
        task_run = replace(
            run if serial else one_thread_each(run), progress=run.progress and serial
        )
        tasks = [RecordingTask(name, Path(rec), out, config, task_run) for name, rec in recordings]
        with open_runner(runner) as live:  # one pool for the recordings and the evaluation
            outcomes = map_recordings(tasks, live, progress=run.progress and not serial)
            failed = tuple((n, o.error) for n, o in outcomes.items() if o.error is not None)
            done = [(n, r) for n, r in recordings if outcomes[n].error is None]
            if not done:  # nothing made: the run fails whole, and leaves no output behind
                if len(recordings) == 1:
                    raise EvalError(failed[0][1])
                msg = f"every recording failed ({', '.join(n for n, _ in failed)}); see above"
                raise EvalError(msg)
            scenes = [plan for (n, _), (plan, has) in zip(recordings, planned, strict=True)
                      if has and outcomes[n].error is None]  # fmt: skip
            unevaluated = [n for (n, _), (_, has) in zip(recordings, planned, strict=True)
                           if not has and outcomes[n].error is None]  # fmt: skip
            report, attempts = None, None
            if scenes:
                report = evaluate(scenes, config.evaluation, out / "eval", run=run)  # on ``live``
                attempts = pq.read_table(out / "eval" / "attempts.parquet")
            evaluated = {scene.name: scene for scene in scenes}
            logs = [
                _log_task(name, out, outcomes[name].grid_due, evaluated.get(name), attempts,
                          report, config)
                for name, _ in done
            ]  # fmt: skip
            for _ in run_tasks(_run_task, [t for t in logs if t.due], live):
                pass
        rrds: list[Path] = []
        for name, _ in done:
            stages = ("ingest", "grid", "instances", "eval")
            rrds += [p for p in (out / f"{name}.{s}.rrd" for s in stages) if p.is_file()]
        stores = tuple(out / "stores" / name for name, _ in done)
        return RunResult(report, stores, tuple(rrds), tuple(unevaluated), failed)
