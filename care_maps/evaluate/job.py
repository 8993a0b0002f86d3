"""The evaluation job: every (scene, query) x strategy x criterion x k, attempt by attempt.

A scene is a fused store (``instances.parquet``, ``cells.parquet``, ``scene_points.parquet``)
plus the ground truth beside its recording. Scenes are independent, so they run in a local
process pool or as Ray tasks; each scene's attempts come back as one Arrow table that the
driver caches as ``scenes/<name>.parquet`` (keyed by the config's fingerprint), so a re-run
skips finished scenes. Every random draw is seeded from (config seed, scene, unit, strategy,
criterion, k, seed index) alone, so results are bit-identical whichever way they ran.

Every attempt sequence also walks (:mod:`care_maps.evaluate.travel`): from the query's start
(:class:`care_maps.evaluate.config.TravelStart`) to the first goal, then from each goal reached to the
next; each attempt row keeps its leg, the path so far and the query's shortest path to a
success (:mod:`care_maps.evaluate.spl`).
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from tqdm import tqdm

from care_maps.core.errors import CareError, EvalError
from care_maps.core.fingerprint import content_digest, fingerprint
from care_maps.core.maps import MapKind
from care_maps.core.outputs import damaged, evaluation_output, read_marker
from care_maps.core.store import META_FILE, read_table, source_recording, write_table_atomic
from care_maps.evaluate.config import NO_CRITERION, EvalConfig, TravelStart, grid_protocol
from care_maps.evaluate.groundtruth import GtSource, check_ground_truth, gt_files
from care_maps.evaluate.report import Report, write_report
from care_maps.evaluate.spl import shortest_to_success
from care_maps.evaluate.success import QuerySet, grid_queries, instance_queries, scene_point_labels
from care_maps.evaluate.travel import SceneTravel, SceneWalks
from care_maps.query.confidence import log_confidence
from care_maps.query.map import MAP_TABLES, REPLAN_COLUMNS, CandidateMap, load_map
from care_maps.replan.attempts import Attempts, run_attempts
from care_maps.replan.expected import expected_random_success
from care_maps.replan.strategies import STRATEGIES, Strategy
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution
from care_maps.runtime.parallel import Runner, open_runner, run_tasks
from care_maps.truth.dataset_index import INDEX_NAME, read_index

__all__ = [
    "ATTEMPT_SCHEMA",
    "EvalConfig",
    "Scene",
    "describe",
    "evaluate_scene",
    "run_eval",
    "run_scenes",
    "scene_query_sets",
    "scenes_of",
]


ATTEMPT_SCHEMA = pa.schema(
    [
        ("scene", pa.string()),
        ("map", pa.string()),
        ("protocol", pa.string()),
        ("unit", pa.string()),
        ("query", pa.string()),
        ("target", pa.string()),
        ("strategy", pa.string()),
        ("criterion", pa.string()),
        ("k", pa.int16()),
        ("seed", pa.int16()),
        ("attempt", pa.int8()),
        ("candidate", pa.int32()),
        ("success", pa.bool_()),
        ("fell_back", pa.bool_()),
        ("set_size", pa.int32()),
        ("value", pa.float32()),
        ("confidence", pa.float32()),
        ("entropy", pa.float32()),
        ("stderr", pa.float32()),
        ("pwkl", pa.float32()),
        ("num_views", pa.int32()),
        ("expected", pa.float32()),
        ("distance", pa.float32()),
        ("walked", pa.float32()),
        ("shortest", pa.float32()),
    ]
)
"""One row per attempt made. ``candidate`` is the id in the scene's map table (-1: nothing
left to choose); ``seed`` is -1 for deterministic strategies; ``expected`` is the closed-form
success probability of the episode for the random strategies (NaN otherwise). Travel (NaN
where the scene has none): ``distance`` the metres from where the robot stood to this
attempt's goal (inf: unreachable), ``walked`` the episode's path so far (this attempt's leg
included where it was reachable), ``shortest`` the query's shortest path to a success
(:func:`care_maps.evaluate.spl.shortest_to_success`; inf: none reachable)."""


@dataclass(frozen=True)
class Scene:
    """One recording's fused store and where its ground truth is."""

    name: str
    store: Path
    recording: Path
    """Recording path; ground truth beside it (by name) is found unless ``gt`` names one."""
    extra: dict[str, str] = field(default_factory=dict, compare=False)
    gt: GtSource = field(default_factory=GtSource)
    """Where the ground truth is and how to read it (:class:`care_maps.evaluate.groundtruth.GtSource`)."""


def _store_recording(store: Path) -> Path:
    if not (store / META_FILE).is_file():
        msg = f"{store}: not a feature store (no meta.json); run `care ingest` and `care fuse`"
        raise EvalError(msg)
    path = source_recording(store)
    if path is None:
        msg = f"{store / META_FILE}: no source recording recorded; the ground truth cannot be found"
        raise EvalError(msg)
    return path


def _find_stores(root: Path) -> dict[Path, Path]:
    """Recording path (resolved) -> store, for every store at most two levels below root."""
    out: dict[Path, Path] = {}
    for meta in [*root.glob("*/meta.json"), *root.glob("*/*/meta.json")]:
        try:
            out[_store_recording(meta.parent).resolve()] = meta.parent
        except CareError:
            continue
    return out


def scenes_of(dataset: Path | Sequence[Path | Scene]) -> list[Scene]:
    """The scenes of a dataset directory (``index.json`` of recordings, their stores found
    below the directory or named by an entry's ``store``, their ground truth by its ``gt``),
    a single store, or a list of stores (each knowing its recording from ``meta.json``) or
    of :class:`Scene`."""
    if not isinstance(dataset, Path | str):
        return [
            s
            for item in dataset
            for s in ([item] if isinstance(item, Scene) else scenes_of(Path(item)))
        ]
    dataset = Path(dataset)
    if (dataset / "meta.json").is_file():
        return [Scene(dataset.name, dataset, _store_recording(dataset))]
    if not (dataset / INDEX_NAME).is_file():
        msg = f"{dataset}: neither a store (meta.json) nor a dataset ({INDEX_NAME})"
        raise EvalError(msg)
    stores = _find_stores(dataset)
    scenes = []
    for entry in read_index(dataset):
        store = entry.store or stores.get(entry.recording.resolve())
        if store is None or not (store / "meta.json").is_file():
            rel = entry.recording.relative_to(dataset)
            msg = (
                f"{dataset / INDEX_NAME}: no fused store for {rel}; run `care ingest {rel}` and "
                "`care fuse` (or `care run`) first"
            )
            raise EvalError(msg)
        source = GtSource.of(entry.gt, entry.gt_format, entry.gt_transform, entry.gt_class_map)
        scenes.append(Scene(entry.name, store, entry.recording.resolve(), gt=source))
    return scenes


def _seed_of(config: EvalConfig, *parts: object) -> np.random.Generator:
    key = zlib.crc32("\x1f".join(map(str, parts)).encode())
    return np.random.default_rng(np.random.SeedSequence([config.seed, key]))


def _combos(config: EvalConfig, kind: str) -> list[tuple[str, str, int, int]]:
    """(strategy, criterion, k, seed) of every episode to play; the oracle first."""
    out: list[tuple[str, str, int, int]] = []
    names = sorted(config.strategies, key=lambda n: not STRATEGIES[n].needs_truth)
    for name in names:
        s = STRATEGIES[name]
        sets = (
            [(c, k) for c in config.criteria for k in config.ks(kind)]
            if s.uses_set
            else [(NO_CRITERION, 0)]
        )
        seeds = range(config.seeds) if s.random else [-1]
        out += [(name, c, k, seed) for c, k in sets for seed in seeds]
    return out


class _EpisodeOptions(TypedDict):
    """The options :func:`evaluate_queries` plays an episode with (and its closed form)."""

    criterion: str
    k: int
    attempts: int
    rank: np.ndarray | None
    positions: np.ndarray | None
    exclude_radius: float


def _empty_attempts(n_q: int, attempts: int) -> Attempts:
    shape = (n_q, attempts)
    return Attempts(
        np.full(shape, -1, np.int64), np.zeros(shape, bool), np.full(shape, np.nan),
        np.zeros(shape, bool), np.zeros(shape, np.int64),
    )  # fmt: skip


def evaluate_queries(
    qs: QuerySet,
    kind: str,
    protocol: str,
    scene: str,
    config: EvalConfig,
    travel: SceneTravel | None = None,
    exclude_radius: float = 0.0,
) -> pa.Table:
    """Every episode of one query set, as attempt rows (:data:`ATTEMPT_SCHEMA`); with
    ``travel`` each walks; on the grid a failed attempt skips the cells within
    ``exclude_radius`` of it (the protocol's)."""
    cmap = qs.cmap
    n_q = len(qs.queries)
    grid = kind == MapKind.GRID
    walk = travel.walk(qs, scene, kind, protocol) if travel and cmap.num_candidates else None
    shortest = (
        shortest_to_success(walk.start, qs.success) if walk is not None else np.full(n_q, np.nan)
    )
    conf: np.ndarray | None
    rank: np.ndarray | None
    if cmap.num_candidates:
        # ranked by log-confidence (docs/method.md): float32 probabilities tie at 1.0 and let the
        # lowest id win; the rows report P itself
        conf = log_confidence(cmap, qs.class_ids)
        rank = (
            cmap.class_rank(qs.class_ids, limit=max(config.ks(kind)))
            if "category" in config.criteria
            else None
        )
    else:
        conf = rank = None
    columns = {m: cmap.column(m) for m in REPLAN_COLUMNS}
    rows: list[dict[str, np.ndarray]] = []
    oracle: np.ndarray | None = None
    expected_of: dict[tuple[str, str, int], np.ndarray] = {}  # the closed form has no seed
    for name, criterion, k, seed in _combos(config, kind):
        strategy = STRATEGIES[name]
        kw: _EpisodeOptions = {
            "criterion": criterion if criterion != NO_CRITERION else "confidence",
            "k": max(k, 1),
            "attempts": config.attempts,
            "rank": rank,
            "positions": cmap.positions if grid else None,
            "exclude_radius": exclude_radius if grid else 0.0,
        }
        if conf is None:
            res = _empty_attempts(n_q, 1)
            expected = np.zeros(n_q) if strategy.random else np.full(n_q, np.nan)
        else:
            rng = _seed_of(config, scene, kind, protocol, qs.unit, name, criterion, k, seed)
            res = _as_probability(
                run_attempts(strategy, conf, qs.success, columns, rng=rng, walk=walk, **kw),
                strategy,
            )
            if strategy.random and (name, criterion, k) not in expected_of:
                expected_of[name, criterion, k] = expected_random_success(
                    strategy, conf, qs.success, **kw
                )
            expected = expected_of.get((name, criterion, k), np.full(n_q, np.nan))
        if strategy.needs_truth:
            oracle = res.solved
        elif oracle is not None and (res.solved & ~oracle).any():
            msg = f"internal error: {name} beat the oracle in {scene}/{qs.unit}; please report"
            raise EvalError(msg)
        rows.append(_attempt_rows(qs, res, conf, name, criterion, k, seed, expected, shortest))
    cols = {key: np.concatenate([r[key] for r in rows]) for key in rows[0]}
    n = len(cols["attempt"])
    const = {"scene": scene, "map": kind, "protocol": protocol, "unit": qs.unit}
    arrays = {key: pa.array([value] * n, pa.string()) for key, value in const.items()}
    arrays.update({key: pa.array(v, ATTEMPT_SCHEMA.field(key).type) for key, v in cols.items()})
    return pa.table([arrays[f.name] for f in ATTEMPT_SCHEMA], schema=ATTEMPT_SCHEMA)


def _as_probability(res: Attempts, strategy: Strategy) -> Attempts:
    """``res`` with the values chosen by log-confidence (first attempts, fallbacks and
    confidence rules) turned back into the probability P_c[y] the tables report."""
    by_conf = res.fell_back.copy()
    by_conf[:, 0] = True
    if strategy.measure == "confidence":
        by_conf[:] = True
    value = np.where(by_conf, np.exp(res.value), res.value)
    return dataclasses.replace(res, value=value)


def _attempt_rows(
    qs: QuerySet,
    res: Attempts,
    conf: np.ndarray | None,
    name: str,
    criterion: str,
    k: int,
    seed: int,
    expected: np.ndarray,
    shortest: np.ndarray,
) -> dict[str, np.ndarray]:
    """Rows of the attempts actually made (attempt 1 always, later ones until success)."""
    made = res.candidate >= 0
    if res.distance is None:
        leg = walked = np.full(made.shape, np.nan)
    else:
        leg = res.distance
        walked = np.cumsum(np.where(made & np.isfinite(leg), leg, 0.0), axis=1)
    made[:, 0] = True
    q, a = np.nonzero(made)
    local = res.candidate[q, a]
    safe = np.maximum(local, 0)
    has = local >= 0
    nothing = np.full(len(q), np.nan)

    def col(values: np.ndarray) -> np.ndarray:
        return np.where(has, values[safe], np.nan) if len(values) else nothing

    return {
        "query": np.asarray(qs.queries, dtype=object)[q],
        "target": np.asarray(qs.targets, dtype=object)[q],
        "strategy": np.full(len(q), name, dtype=object),
        "criterion": np.full(len(q), criterion, dtype=object),
        "k": np.full(len(q), k),
        "seed": np.full(len(q), seed),
        "attempt": a + 1,
        "candidate": np.where(has, qs.candidate_ids[safe] if len(qs.candidate_ids) else -1, -1),
        "success": res.success[q, a],
        "fell_back": res.fell_back[q, a],
        "set_size": res.set_size[q, a],
        "value": res.value[q, a],
        "confidence": (
            nothing
            if conf is None
            else np.where(has, np.exp(conf[q, safe].astype(np.float64)), np.nan)
        ),
        "entropy": col(qs.cmap.entropy),
        "stderr": col(qs.cmap.stderr),
        "pwkl": col(qs.cmap.pwkl),
        "num_views": np.where(has, col(qs.cmap.num_views), 0),
        "expected": expected[q],
        "distance": leg[q, a],
        "walked": walked[q, a],
        "shortest": shortest[q],
    }


def evaluate_scene(scene: Scene, config: EvalConfig) -> pa.Table:
    """All attempt rows of one scene (every map kind and protocol of ``config``).

    BLAS and torch run on :data:`care_maps.runtime.threads.THREADS` [EVAL] (one) thread here: a float32 matrix product sums in an order that depends on
    the thread count, and its last bits decide near-ties between candidates, so a Ray
    worker (one thread) and a pool process (all cores) would otherwise choose differently.
    Scenes run in parallel anyway.
    """
    from care_maps.runtime.threads import Work, threads_for

    with threads_for(Work.EVAL):
        return _evaluate_scene(scene, config)


def scene_query_sets(
    scene: Scene, config: EvalConfig
) -> Iterator[tuple[MapKind, CandidateMap, str, float, list[QuerySet]]]:
    """Every query set of a scene as the evaluation plays it: ``(map kind, its map,
    protocol, exclusion radius, query sets)`` per instance-query protocol and per grid
    exclusion radius (one protocol each, the grid's query sets shared between them)."""
    gt = scene.gt.load(scene.recording, scene.store)
    for kind in config.maps:
        if not (scene.store / f"{MAP_TABLES[kind]}.parquet").is_file():
            msg = f"{scene.store}: no {MAP_TABLES[kind]}.parquet; run `care fuse` (or drop --maps {kind})"
            raise EvalError(msg)
        cmap = load_map(scene.store, kind)
        if kind == MapKind.INSTANCES:
            labels = scene_point_labels(scene.store, gt, config.label_distance)
            for protocol in config.protocols:
                sets = instance_queries(
                    cmap, gt, labels, protocol=protocol, rooms=config.rooms,
                    iou_threshold=config.iou_threshold,
                )  # fmt: skip
                yield kind, cmap, protocol, 0.0, sets
        else:
            sets = grid_queries(cmap, gt, rooms=config.rooms, radius=config.success_radius)
            for radius in config.exclude_radii:
                yield kind, cmap, grid_protocol(radius), radius, sets


def _evaluate_scene(scene: Scene, config: EvalConfig) -> pa.Table:
    tables = []
    walks = SceneWalks(scene.store, config)  # one roadmap for both maps
    travel: dict[MapKind, SceneTravel | None] = {}
    for kind, cmap, protocol, radius, sets in scene_query_sets(scene, config):
        if kind not in travel:
            travel[kind] = walks.for_map(cmap)
        tables += [
            evaluate_queries(
                qs, kind, protocol, scene.name, config, travel[kind], exclude_radius=radius
            )
            for qs in sets
        ]
    if not tables:
        return ATTEMPT_SCHEMA.empty_table()
    return pa.concat_tables(tables)


def _cache_path(out: Path, scene: Scene) -> Path:
    return out / "scenes" / f"{scene.name}.parquet"


EVAL_VERSION = 5
"""Raised whenever the attempts of an unchanged scene and config would change, so that cached
attempts written by other code are computed again."""
SCENE_KEY = b"care.eval.scene_key"
"""Metadata of a scene's cached attempts: what they were computed from (config and inputs)."""
EVAL_FINGERPRINT_KEY = b"care.eval.fingerprint"
"""Metadata of a scene's cached attempts: the evaluation config's fingerprint."""


def _scene_key(scene: Scene, config: EvalConfig) -> bytes:
    """What a cached scene's attempts depend on: the config, the evaluation code's version,
    and the content (size and checksum) of the scene's map tables and ground-truth files:
    a re-fused map or a regenerated scene is not served from the cache, and a dataset moved
    to another directory or machine keeps it."""
    files = [scene.store / f"{MAP_TABLES[kind]}.parquet" for kind in config.maps]
    files += [scene.store / "scene_points.parquet", *gt_files(scene.gt, scene.recording)]
    recorded = (read_marker(scene.store) or {}).get("tables") or {}
    contents = [
        (p.name, (recorded.get(p.name) if p.parent == scene.store else None) or content_digest(p))
        for p in files
        if p.is_file()
    ]
    gt = scene.gt  # how it is read; its files are in ``contents``, wherever they lie
    how = (gt.fmt, gt.transform, None if gt.class_map is None else Path(gt.class_map).name)
    key = fingerprint(config.fingerprint(), EVAL_VERSION, contents, how)
    return key[:16].encode()


def _cached(out: Path, scene: Scene, config: EvalConfig) -> bool:
    """Whether ``out`` holds the scene's attempts for ``config``, whole (a cached table
    that is damaged, or unreadable, is evaluated again)."""
    path = _cache_path(out, scene)
    if not path.is_file() or damaged(out, [path.relative_to(out).as_posix()], checksum=False):
        return False
    try:
        md = pq.read_schema(path).metadata or {}
    except (OSError, pa.ArrowException):
        return False
    return md.get(SCENE_KEY) == _scene_key(scene, config)


@dataclass(frozen=True)
class _SceneTask:
    """One scene's evaluation as a task of :func:`care_maps.runtime.parallel.run_tasks` (picklable)."""

    config: EvalConfig

    def __call__(self, scene: Scene) -> pa.Table:
        return evaluate_scene(scene, self.config)


def run_scenes(
    scenes: Sequence[Scene],
    config: EvalConfig,
    out: Path,
    *,
    run: Execution = DEFAULT_EXECUTION,
) -> pa.Table:
    """Evaluate every scene not cached under ``out/scenes``; return all attempt rows.

    The scenes run where ``run`` says (:meth:`care_maps.runtime.parallel.Runner.of`: a local process
    pool of ``run.workers`` processes, default one per CPU, or Ray), on the open pool of
    a caller with the same settings (:func:`care_maps.runtime.parallel.open_runner`).
    """
    out = Path(out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    names = [s.name for s in scenes]
    if len(set(names)) != len(names):
        msg = f"scene names must be unique, got {sorted(n for n in names if names.count(n) > 1)}"
        raise EvalError(msg)
    todo = [s for s in scenes if not _cached(out, s, config)]
    with open_runner(Runner.of(run)) as runner:
        results = run_tasks(_SceneTask(config), todo, runner)
        bar = tqdm(results, total=len(todo), desc="scenes", disable=not run.progress)
        for scene, table in bar:
            md = {
                EVAL_FINGERPRINT_KEY: config.fingerprint().encode(),
                SCENE_KEY: _scene_key(scene, config),
            }
            write_table_atomic(table, _cache_path(out, scene), md)
    tables = [read_table(_cache_path(out, s)).cast(ATTEMPT_SCHEMA) for s in scenes]
    return pa.concat_tables(tables) if tables else ATTEMPT_SCHEMA.empty_table()


def describe(config: EvalConfig, scenes: Sequence[Scene], attempts: pa.Table) -> str:
    """The header of ``results.md``: what was evaluated and how (protocol, rooms, attempts)."""
    units = attempts.group_by(["scene", "map", "unit"], use_threads=False).aggregate([])
    by_room = units.filter(pc.not_equal(units.column("unit"), "scene")).num_rows
    rooms = (
        f"room by room ({by_room} room maps: each room's candidates are those whose centre lies in it)"
        if by_room
        else "whole scenes (no rooms in the ground truth, or --no-rooms)"
    )
    return "\n".join(
        [
            f"# CARe evaluation: {len(scenes)} scene(s)\n",
            f"- maps: {', '.join(config.maps)}; instance query protocols: {', '.join(config.protocols)} "
            "(`instance` = one query per GT instance, must match that instance, the paper's; "
            "`class` = one query per class present, any instance of it)",
            f"- evaluated {rooms}",
            f"- success within {config.attempts} attempt(s); instance success: point IoU > "
            f"{config.iou_threshold}; grid success: floor distance <= {config.success_radius} m; "
            "grid protocols (after a failed grid attempt, cells within the radius are skipped): "
            + ", ".join(f"`{grid_protocol(r)}` ({r:g} m)" for r in config.exclude_radii),
            f"- random strategies: mean over {config.seeds} seeds, and the closed form S/U",
            f"- travel: {_WALKS[config.travel_start]}"
            + (
                ""
                if config.travel_start == TravelStart.OFF
                else f"; robot radius {config.clearance} m, on the store's free space"
            ),
            f"- ground truth: {_gt_summary(scenes)}",
            f"- config fingerprint `{config.fingerprint()}`\n",
        ]
    )


_WALKS = {
    TravelStart.FIRST_POSE: "each attempt sequence walks from the recording's first pose",
    TravelStart.FREE_SPACE: "each attempt sequence walks from a seeded free-space cell per query",
    TravelStart.OFF: "off (no path length or SPL)",
}
"""How the report's header says where the walks start."""


def with_ground_truth(
    scenes: Sequence[Scene], gt: Sequence[Path] = (), defaults: GtSource | None = None
) -> list[Scene]:
    """Scenes with the ground truth the user named: ``gt`` (one file per scene, in order)
    and ``defaults`` (format, transform, class map) for scenes whose index named none."""
    scenes = list(scenes)
    if gt and len(gt) != len(scenes):
        msg = (
            f"--gt given {len(gt)} time(s) for {len(scenes)} scene(s); give one per scene, in "
            "order, or name each scene's ground truth in index.json ('gt')"
        )
        raise EvalError(msg)
    defaults = defaults or GtSource()
    out = []
    for i, scene in enumerate(scenes):
        own = scene.gt
        source = GtSource(
            Path(gt[i]) if gt else own.path,
            own.fmt or defaults.fmt,
            own.transform or defaults.transform,
            own.class_map or defaults.class_map,
        )
        out.append(Scene(scene.name, scene.store, scene.recording, scene.extra, source))
    return out


def check_scenes(scenes: Sequence[Scene], config: EvalConfig) -> dict[str, list[str]]:
    """Read and check every scene's ground truth before anything is evaluated (one bad scene
    stops the run before any output is written); returns the classes left out per scene."""
    left_out = {}
    for scene in scenes:
        gt = scene.gt.load(scene.recording, scene.store)
        where = f"{scene.gt.resolve(scene.recording)[0]} (ground truth of {scene.name})"
        left_out[scene.name] = check_ground_truth(
            gt, where=where, store=scene.store, maps=config.maps,
            label_distance=config.label_distance, unknown=config.unknown_classes,
        )  # fmt: skip
    return left_out


def _gt_summary(scenes: Sequence[Scene]) -> str:
    """How the scenes' ground truth was found (formats, transforms), for the report header."""
    kinds = set()
    for scene in scenes:
        try:
            path, fmt = scene.gt.resolve(scene.recording)
        except CareError:
            continue
        from care_maps.truth.load import detect_format

        kind = (fmt or detect_format(path)).value
        kinds.add(kind + (" + --gt-transform" if scene.gt.transform else ""))
    return (
        ", ".join(sorted(kinds))
        + "; instances with points are judged by point IoU, box-only instances by the IoU with "
        "the map points inside their box"
    )


def run_eval(
    dataset: Path | Sequence[Path | Scene],
    config: EvalConfig,
    out: Path,
    *,
    run: Execution = DEFAULT_EXECUTION,
    gt: Sequence[Path] = (),
    gt_defaults: GtSource | None = None,
) -> Report:
    """Evaluate a dataset (see :func:`scenes_of`) and write every output under ``out``.

    ``run``: where the scenes run and whether progress shows (:func:`run_scenes`);
    ``gt``: one ground-truth file per scene (else each scene's own, see :class:`Scene`);
    ``gt_defaults``: format, transform and class map for scenes that name none."""
    scenes = with_ground_truth(scenes_of(dataset), gt, gt_defaults)
    left_out = check_scenes(scenes, config)
    out = Path(out)
    # written into a staged copy of ``out`` that replaces it whole at the end: a kill at any
    # instant leaves the previous results or the new ones, never some of each
    with (
        evaluation_output(out, [s.store for s in scenes]) as staged,
        open_runner(Runner.of(run)) as live,
    ):
        attempts = run_scenes(scenes, config, staged, run=run)
        ks: dict[str, Sequence[int]] = {kind: config.ks(kind) for kind in MAP_TABLES}
        header = describe(config, scenes, attempts)
        dropped = {name: classes for name, classes in left_out.items() if classes}
        if dropped:
            header += (
                "- ground-truth classes not in the vocabulary, left out (--gt-unknown-classes ignore): "
                + "; ".join(f"{name}: {', '.join(classes)}" for name, classes in dropped.items())
                + "\n"
            )
        start = {TravelStart.FIRST_POSE: " from the recording's first pose",
                 TravelStart.FREE_SPACE: " from a seeded free-space cell per query"}  # fmt: skip
        report = write_report(
            attempts, staged, ks, bootstrap=config.bootstrap, header=header, runner=live,
            walk_from=start.get(config.travel_start, ""),
        )  # fmt: skip
    paths = tuple(out / p.relative_to(staged) for p in report.paths)
    return dataclasses.replace(report, paths=paths)
